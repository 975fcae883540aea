// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/learned_shaft_detector.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <optional>
#include <opencv2/dnn.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "endo_guidance/perception/image_reduction.h"
#include "endo_guidance/perception/rectification.h"

namespace endo_guidance::perception {

namespace fs = std::filesystem;

std::string defaultShaftModel() { return std::string(ENDO_GUIDANCE_MODEL_DIR) + "/shaft_net.yaml"; }

struct ShaftNet::Impl {
  cv::dnn::Net net;
  cv::Mat resized, blob;
};

ShaftNet::ShaftNet(std::string const& yaml_path, int threads) : impl_(std::make_unique<Impl>()) {
  std::string const path = yaml_path.empty() ? defaultShaftModel() : yaml_path;
  auto fail = [&](std::string const& why) { throw std::runtime_error("shaft model '" + path + "': " + why); };
  if (!fs::is_regular_file(path)) fail("no such file");
  cv::FileStorage f;
  try {
    f.open(path, cv::FileStorage::READ);
  } catch (cv::Exception const& e) {
    fail(std::string("not a readable YAML file (") + e.what() + ")");
  }
  if (!f.isOpened()) fail("not a readable YAML file");
  std::string onnx = f["model"].empty() ? std::string() : static_cast<std::string>(f["model"]);
  int const w = f["width"].empty() ? 0 : static_cast<int>(f["width"]);
  int const h = f["height"].empty() ? 0 : static_cast<int>(f["height"]);
  if (onnx.empty()) fail("no 'model' (the ONNX file)");
  if (w < 8 || h < 8 || w > 4096 || h > 4096) fail("'width' and 'height' must be in [8, 4096]");
  size_ = cv::Size(w, h);
  mean_ = f["mean"].empty() ? 0.0 : static_cast<double>(f["mean"]);
  scale_ = f["scale"].empty() ? 1.0 : static_cast<double>(f["scale"]);
  if (!(scale_ > 0.0) || !std::isfinite(mean_)) fail("'scale' must be positive and 'mean' finite");
  for (auto const& c : f["classes"]) classes_.push_back(static_cast<std::string>(c));
  auto const it = std::find(classes_.begin(), classes_.end(), "shaft");
  if (it == classes_.end()) fail("'classes' has no 'shaft'");
  shaft_ = static_cast<int>(it - classes_.begin());
  if (fs::path(onnx).is_relative()) onnx = (fs::path(path).parent_path() / onnx).string();
  if (!fs::is_regular_file(onnx)) fail("its ONNX file '" + onnx + "' is missing");
  try {
    impl_->net = cv::dnn::readNetFromONNX(onnx);
  } catch (cv::Exception const& e) {
    fail("OpenCV cannot load '" + onnx + "': " + e.what());
  }
  if (impl_->net.empty()) fail("OpenCV cannot load '" + onnx + "'");
  impl_->net.setPreferableBackend(cv::dnn::DNN_BACKEND_OPENCV);
  impl_->net.setPreferableTarget(cv::dnn::DNN_TARGET_CPU);
  if (threads < 1) fail("threads must be >= 1");
  cv::setNumThreads(threads);  // (OpenCV's DNN layers use the global thread pool)
  // One forward pass now: a model whose layers OpenCV cannot run fails here, with its shape checked.
  cv::Mat const out = logits(cv::Mat(size_, CV_8UC3, cv::Scalar::all(0)));
  if (out.dims != 4 || out.size[1] != static_cast<int>(classes_.size()) || out.size[2] != h || out.size[3] != w)
    fail("its output is not classes x height x width logits");
}

ShaftNet::~ShaftNet() = default;

cv::Mat ShaftNet::logits(cv::Mat const& bgr) {
  CV_Assert(bgr.type() == CV_8UC3 && !bgr.empty());
  // Reduced as in training (area averaging), then (BGR - mean) * scale, channels in BGR order.
  cv::resize(bgr, impl_->resized, size_, 0, 0, bgr.cols > size_.width ? cv::INTER_AREA : cv::INTER_LINEAR);
  cv::dnn::blobFromImage(impl_->resized, impl_->blob, scale_, cv::Size(), cv::Scalar::all(mean_), false, false, CV_32F);
  impl_->net.setInput(impl_->blob);
  return impl_->net.forward();
}

cv::Mat ShaftNet::shaftProbability(cv::Mat const& bgr) {
  cv::Mat const out = logits(bgr);
  int const n = size_.area(), k = static_cast<int>(classes_.size());
  auto const* l = out.ptr<float>();
  cv::Mat prob(size_, CV_32F);
  auto* p = prob.ptr<float>();
  for (int i = 0; i < n; ++i) {  // softmax over the classes, the shaft's share
    float m = l[i];
    for (int c = 1; c < k; ++c) m = std::max(m, l[c * n + i]);
    float s = 0.f;
    for (int c = 0; c < k; ++c) s += std::exp(l[c * n + i] - m);
    p[i] = std::exp(l[shaft_ * n + i] - m) / s;
  }
  return prob;
}

namespace {

// A Region of one mask (CV_8U, box-sized, at box.tl()): its outer boundary, and its seed at the
// middle of its longest run of boundary points on the view's edge (or, off the edge, its boundary
// point nearest to it).
std::optional<Region> maskRegion(cv::Mat const& mask, cv::Rect const& box, FieldOfView const& fov, int border_margin) {
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(mask, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE, box.tl());
  if (contours.empty()) return std::nullopt;
  Region r;
  r.boundary = std::move(*std::max_element(contours.begin(), contours.end(), [](auto const& a, auto const& b) { return a.size() < b.size(); }));
  r.box = box;
  r.area = cv::countNonZero(mask);
  auto const& B = r.boundary;
  int const m = static_cast<int>(B.size());
  std::vector<char> edge(static_cast<std::size_t>(m));
  for (int i = 0; i < m; ++i) edge[i] = nearViewEdge(fov, B[i], border_margin);
  int best_len = 0, best_mid = -1;
  int const start = static_cast<int>(std::find(edge.begin(), edge.end(), 0) - edge.begin());  // a point off the edge
  if (start < m)
    for (int j = 0, len = 0; j <= m; ++j) {
      int const i = (start + j) % m;
      if (j < m && edge[i]) {
        ++len;
        continue;
      }
      if (len > best_len) {
        best_len = len;
        best_mid = (start + j - (len + 1) / 2) % m;
      }
      len = 0;
    }
  if (best_mid >= 0) {
    r.seed = B[best_mid];
  } else {
    r.seed = B.front();
    float dmin = std::numeric_limits<float>::max();
    for (cv::Point const& q : B)
      if (float const d = fov.depth.empty() ? 0.f : fov.depth.at<float>(q); d < dmin) {
        dmin = d;
        r.seed = q;
      }
  }
  return r;
}

// A component that enters the view at several places is several shafts joined (tips touching,
// crossing): each of its pixels goes to the entry nearest to it along the component (a
// breadth-first front from each entry's pixels on the view's edge, 4-connected). One mask per
// entry of at least `min_entry` px; the whole component when it has fewer than two.
std::vector<cv::Mat> splitByEntry(cv::Mat const& comp, cv::Rect const& box, FieldOfView const& fov, int border_margin, int min_entry) {
  cv::Mat edge = cv::Mat::zeros(comp.size(), CV_8U);
  for (int y = 0; y < comp.rows; ++y)
    for (int x = 0; x < comp.cols; ++x)
      if (comp.at<std::uint8_t>(y, x) && nearViewEdge(fov, cv::Point(x, y) + box.tl(), border_margin)) edge.at<std::uint8_t>(y, x) = 255;
  cv::Mat entries, stats, centroids;
  int const n = cv::connectedComponentsWithStats(edge, entries, stats, centroids, 8, CV_32S);
  std::vector<int> keep;
  for (int k = 1; k < n; ++k)
    if (stats.at<int>(k, cv::CC_STAT_AREA) >= min_entry) keep.push_back(k);
  if (keep.size() < 2) return {comp};
  cv::Mat owner(comp.size(), CV_32S, cv::Scalar(-1));
  std::vector<cv::Point> front;
  for (int y = 0; y < comp.rows; ++y)
    for (int x = 0; x < comp.cols; ++x)
      if (int const e = entries.at<int>(y, x); e > 0) {
        auto const it = std::find(keep.begin(), keep.end(), e);
        if (it == keep.end()) continue;
        owner.at<int>(y, x) = static_cast<int>(it - keep.begin());
        front.emplace_back(x, y);
      }
  for (std::size_t i = 0; i < front.size(); ++i) {
    cv::Point const q = front[i];
    for (cv::Point const d : {cv::Point(1, 0), cv::Point(-1, 0), cv::Point(0, 1), cv::Point(0, -1)}) {
      cv::Point const r = q + d;
      if (r.x < 0 || r.y < 0 || r.x >= comp.cols || r.y >= comp.rows || !comp.at<std::uint8_t>(r) || owner.at<int>(r) >= 0) continue;
      owner.at<int>(r) = owner.at<int>(q);
      front.push_back(r);
    }
  }
  std::vector<cv::Mat> out;
  for (std::size_t k = 0; k < keep.size(); ++k) out.push_back(owner == static_cast<int>(k));
  return out;
}

}  // namespace

std::vector<Region> proposeShaftRegions(cv::Mat const& shaft_probability, FieldOfView const& fov, int min_area,
                                        int border_margin) {
  CV_Assert(shaft_probability.type() == CV_32F && !fov.mask.empty());
  cv::Mat p = shaft_probability, mask;
  if (p.size() != fov.mask.size()) cv::resize(shaft_probability, p, fov.mask.size(), 0, 0, cv::INTER_LINEAR);
  cv::compare(p, 0.5, mask, cv::CMP_GE);
  mask &= fov.mask;
  cv::morphologyEx(mask, mask, cv::MORPH_OPEN, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(3, 3)));
  cv::Mat labels, stats, centroids;
  int const n = cv::connectedComponentsWithStats(mask, labels, stats, centroids, 8, CV_32S);
  std::vector<Region> out;
  for (int k = 1; k < n; ++k) {
    if (stats.at<int>(k, cv::CC_STAT_AREA) < min_area) continue;
    cv::Rect const box(stats.at<int>(k, cv::CC_STAT_LEFT), stats.at<int>(k, cv::CC_STAT_TOP), stats.at<int>(k, cv::CC_STAT_WIDTH),
                       stats.at<int>(k, cv::CC_STAT_HEIGHT));
    // (an entry as wide as the thinnest shaft the fit accepts, at the processing scale)
    for (cv::Mat const& part : splitByEntry(labels(box) == k, box, fov, border_margin, 3))
      if (cv::countNonZero(part) >= min_area)
        if (auto r = maskRegion(part, box, fov, border_margin)) out.push_back(std::move(*r));
  }
  // Largest first: the contour fit claims in this order.
  std::sort(out.begin(), out.end(), [](Region const& a, Region const& b) { return a.area > b.area; });
  return out;
}

// A mask's outline wanders along the view's edge: its points that near it are the entry.
constexpr int kMaskEdgeMargin = 3;

SideFit maskSides(Region const& region, FieldOfView const& fov, int scale, ContourLinesParams const& params) {
  SideFit fit;
  fit.rejection = ContourRejection::kTooFewPoints;
  cv::Moments const mo = cv::moments(region.boundary);
  if (!(mo.m00 > 0.0)) return fit;
  Eigen::Vector2d const c(mo.m10 / mo.m00, mo.m01 / mo.m00);
  double const th = 0.5 * std::atan2(2.0 * mo.mu11, mo.mu20 - mo.mu02);
  Eigen::Vector2d d(std::cos(th), std::sin(th));
  Eigen::Vector2d const seed(region.seed.x, region.seed.y);
  if (d.dot(c - seed) < 0.0) d = -d;  // from the entry into the view
  Eigen::Vector2d const n(-d.y(), d.x());
  std::vector<Eigen::Vector2d> off_edge;
  std::vector<double> across;
  double t_far = -std::numeric_limits<double>::infinity();
  for (cv::Point const& q : region.boundary) {
    if (nearViewEdge(fov, q, kMaskEdgeMargin * params.border_margin)) continue;
    Eigen::Vector2d const x(q.x, q.y);
    off_edge.push_back(x);
    across.push_back(std::abs(n.dot(x - c)));
    t_far = std::max(t_far, d.dot(x - seed));
  }
  if (off_edge.empty()) return fit;
  std::nth_element(across.begin(), across.begin() + static_cast<std::ptrdiff_t>(across.size() / 2), across.end());
  double const width = 2.0 * across[across.size() / 2];
  std::array<std::vector<Eigen::Vector2d>, 2> side;
  for (Eigen::Vector2d const& x : off_edge)
    if (d.dot(x - seed) < t_far - width) side[n.dot(x - c) < 0.0 ? 0 : 1].push_back(toFullRes(x, scale));
  for (int k = 0; k < 2; ++k) {
    if (static_cast<int>(side[k].size()) < params.min_side_points) return fit;
    auto const l = fitLineLMedS(side[k], params.lmeds_samples, params.seed + static_cast<std::uint64_t>(k));
    if (!l || static_cast<double>(l->inliers.size()) < params.min_inlier_fraction * static_cast<double>(side[k].size())) {
      fit.rejection = ContourRejection::kNotStraight;
      return fit;
    }
    Eigen::Vector3d line = l->line;
    if (line.dot(toFullRes(c, scale).homogeneous()) < 0.0) line = -line;  // the shaft on its positive side
    fit.lines[k] = line;
    for (int i : l->inliers) fit.points[k].push_back(side[k][static_cast<std::size_t>(i)]);
    fit.inliers += static_cast<int>(l->inliers.size());
  }
  fit.entry = toFullRes(seed, scale);
  setFarEnd(fit);
  fit.rejection = ContourRejection::kNone;
  return fit;
}

ContourFit maskContour(SideFit const& sides, Region const& region, int scale, ContourLinesParams const& params,
                       double sigma_floor_px) {
  ContourFit fit;
  auto reject = [&](ContourRejection r) {
    fit.rejection = r;
    return fit;
  };
  Eigen::Vector2d const along = sides.far - sides.entry;
  std::array<Eigen::Vector2d, 2> dir;
  for (int k = 0; k < 2; ++k) {
    dir[k] = Eigen::Vector2d(-sides.lines[k].y(), sides.lines[k].x());
    if (dir[k].dot(along) < 0.0) dir[k] = -dir[k];
  }
  if (std::acos(std::clamp(dir[0].dot(dir[1]), -1.0, 1.0)) > params.max_angle_deg * M_PI / 180.0)
    return reject(ContourRejection::kNotParallel);
  Eigen::Vector2d const axis = (dir[0] + dir[1]).normalized();
  Eigen::Vector2d const left(axis.y(), -axis.x());
  int const L = sides.lines[0].head<2>().dot(left) < 0.0 ? 0 : 1;  // normal pointing right: the left line
  if (!(sides.lines[L].head<2>().dot(left) < 0.0 && sides.lines[1 - L].head<2>().dot(left) > 0.0))
    return reject(ContourRejection::kCrossing);
  geometry::ApparentContour c;
  c.lines = {sides.lines[L], sides.lines[1 - L]};
  c.entry_px = sides.entry;
  c.tip_px = sides.far;
  fit.edges = {sides.points[L], sides.points[1 - L]};
  auto const fitted = rectifyContour(c, fit.edges, [](Eigen::Vector2d const& q) { return q; }, params.min_side_points, sigma_floor_px);
  if (!fitted) return reject(ContourRejection::kTooFewPoints);
  c = *fitted;
  geometry::ImageLine const ax = geometry::imageAxis(c);
  c.entry_px = geometry::footOnLine(ax, c.entry_px);
  Eigen::Vector2d const u = (geometry::footOnLine(ax, c.tip_px) - c.entry_px).normalized();
  double t_tip = u.dot(c.tip_px - c.entry_px);
  for (cv::Point const& q : region.boundary) {  // the region's end between the lines (its jaws are another class)
    Eigen::Vector3d const x = toFullRes(Eigen::Vector2d(q.x, q.y), scale).homogeneous();
    if (c.lines[0].dot(x) >= -scale && c.lines[1].dot(x) >= -scale) t_tip = std::max(t_tip, u.dot(x.head<2>() - c.entry_px));
  }
  c.tip_px = c.entry_px + t_tip * u;
  double const length = (c.tip_px - c.entry_px).norm();
  double const w_entry = geometry::shaftWidthAt(c, c.entry_px), w_tip = geometry::shaftWidthAt(c, c.tip_px);
  if (c.residual_px > params.max_residual_px) return reject(ContourRejection::kResidual);
  if (length < params.min_length_px) return reject(ContourRejection::kTooShort);
  if (std::min(w_entry, w_tip) < params.min_width_px) return reject(ContourRejection::kTooThin);
  if (length < params.min_elongation * 0.5 * (w_entry + w_tip)) return reject(ContourRejection::kNotElongated);
  if (params.max_widening > 0.0 && w_tip > params.max_widening * w_entry) return reject(ContourRejection::kWidens);
  fit.contour = c;
  fit.edge_points = static_cast<int>(fit.edges[0].size() + fit.edges[1].size());
  return fit;
}

bool agreesWithMask(geometry::ApparentContour const& c, SideFit const& sides, double gate_px) {
  auto median = [](std::vector<Eigen::Vector2d> const& pts, geometry::ImageLine const& l) {
    std::vector<double> d;
    for (auto const& q : pts) d.push_back(std::abs(l.dot(q.homogeneous())));
    if (d.empty()) return std::numeric_limits<double>::infinity();
    std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
    return d[d.size() / 2];
  };
  double const straight = std::max(median(sides.points[0], c.lines[0]), median(sides.points[1], c.lines[1]));
  double const crossed = std::max(median(sides.points[0], c.lines[1]), median(sides.points[1], c.lines[0]));
  return std::min(straight, crossed) <= gate_px;
}


namespace {
// One mask component's contour: the lines on the frame's edges where they are the mask's sides,
// else on the mask's sides; kNone in its rejection when accepted.
ContourFit fitComponent(Region const& region, DetectionFrame const& frame, ContourLinesParams const& p, double gate_px,
                        double mask_floor_px, std::vector<geometry::ApparentContour> const& found) {
  SideFit const sides = maskSides(region, frame.fov, frame.scale, p);
  if (sides.rejection != ContourRejection::kNone) {
    ContourFit none;
    none.rejection = sides.rejection;
    return none;
  }
  ContourFit f = refineContour(sides, region, frame.fov, frame.bgr, frame.scale, p);
  if (!f.contour || !agreesWithMask(*f.contour, sides, gate_px)) f = maskContour(sides, region, frame.scale, p, mask_floor_px);
  if (f.contour && mostlyGlare(frame.bgr, *f.contour, p)) f.rejection = ContourRejection::kGlare;
  else if (f.contour && duplicatesAShaft(*f.contour, found)) f.rejection = ContourRejection::kDuplicate;
  if (f.rejection != ContourRejection::kNone) f.contour.reset();
  return f;
}

// The network for p: `current` when it is still the one p asks for.
std::shared_ptr<ShaftNet> networkFor(SegmentationParams const& p, SegmentationParams const& old, std::shared_ptr<ShaftNet> current) {
  if (current && p.learned.model == old.learned.model && p.learned.threads == old.learned.threads) return current;
  return std::make_shared<ShaftNet>(p.learned.model, p.learned.threads);
}
}  // namespace

LearnedShaftDetector::LearnedShaftDetector(SegmentationParams const& params)
    : params_(params), net_(networkFor(params, params, nullptr)) {}

void LearnedShaftDetector::setParams(SegmentationParams const& p) {
  net_ = networkFor(p, params_, net_);  // (throws before anything changed)
  params_ = p;
}

SegmentationResult LearnedShaftDetector::detect(DetectionFrame const& frame) {
  SegmentationResult res;
  res.scale = frame.scale;
  cv::Mat const prob = net_->shaftProbability(frame.bgr);
  cv::Mat p;  // at the processing scale
  cv::resize(prob, p, frame.fov.mask.size(), 0, 0, cv::INTER_LINEAR);
  res.regions = proposeShaftRegions(p, frame.fov, params_.regions.min_area, params_.contours.border_margin);
  labels_ = cv::Mat::zeros(frame.fov.mask.size(), CV_8U);
  // A mask side is as good as the network's resolution: an image edge farther than 1.5 of its
  // pixels from it is another edge; a line on the mask's side has its pixel's quantisation
  // error (pixel / sqrt(12)) as the systematic floor of its covariance.
  double const net_px = static_cast<double>(frame.bgr.cols) / prob.cols;
  double const mask_floor_px = std::max(params_.contours.line_sigma_floor_px, net_px / std::sqrt(12.0));
  for (std::size_t ri = 0; ri < res.regions.size() && static_cast<int>(res.contours.size()) < params_.regions.max_regions; ++ri) {
    ContourFit const f = fitComponent(res.regions[ri], frame, params_.contours, 1.5 * net_px, mask_floor_px, res.contours);
    res.region_status.push_back(f.rejection);
    if (!f.contour) continue;
    res.contours.push_back(onImageAxis(*f.contour));  // (reported on the image axis, as the colour method's)
    res.edges.push_back(f.edges);
    res.contour_regions.push_back(ri);
    cv::drawContours(labels_, std::vector<std::vector<cv::Point>>{res.regions[ri].boundary}, 0,
                     cv::Scalar(static_cast<int>(res.contours.size())), cv::FILLED);
  }
  res.regions.resize(res.region_status.size());  // (those beyond max_regions were not fitted)
  std::vector<std::size_t> none;
  removeDuplicateShafts(res, none);
  p.convertTo(feature_, CV_8U, -255.0, 255.0);  // low on shafts, as the colour feature
  return res;
}

}  // namespace endo_guidance::perception
