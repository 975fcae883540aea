// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/colour_shaft_detector.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <numeric>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/image_reduction.h"
#include "endo_guidance/perception/sigma_filter.h"

namespace endo_guidance::perception {

namespace {
// Whether seeds a and b (on the region's boundary) are joined by a stretch of the boundary that
// runs along the field-of-view edge (no deeper inside than the seeds, plus `margin` px): the two
// are one entry.
bool onOneBorderRun(Region const& r, FieldOfView const& fov, cv::Point a, cv::Point b, int margin) {
  auto const& B = r.boundary;
  int const n = static_cast<int>(B.size());
  if (n == 0) return false;
  auto nearest = [&](cv::Point q) {
    int bi = 0;
    double bd = 1e300;
    for (int i = 0; i < n; ++i)
      if (double const d = cv::norm(B[i] - q); d < bd) {
        bd = d;
        bi = i;
      }
    return bi;
  };
  float const level = std::max(fov.depth.at<float>(a), fov.depth.at<float>(b)) + static_cast<float>(margin);
  auto onBorder = [&](cv::Point q) { return fov.depth.at<float>(q) <= level; };
  int const ia = nearest(a), ib = nearest(b);
  for (int step : {1, -1}) {
    bool run = true;
    for (int i = ia; i != ib && run; i = ((i + step) % n + n) % n) run = onBorder(B[i]);
    if (run) return true;
  }
  return false;
}

// Whether a shaft found from a crossing seed (entering the view at an accepted shaft, label
// `occluder` in `labels`) continues on that shaft's other side, as a shaft passing under or over
// it does: walking back along its image axis from the entry, the occluder's pixels are met within
// a few px, and the 4 px beyond them are mostly (3 of 4) inside the view and at or below the
// growth level. A blob or a jaw beside the occluder ends at it.
bool continuesBeyond(geometry::ApparentContour const& c, cv::Mat const& labels, int occluder, cv::Mat const& feature, FieldOfView const& fov,
                     int level, int scale) {
  Eigen::Vector2d const d = (c.entry_px - c.tip_px).normalized();
  Eigen::Vector2d const e = toProcessing(geometry::footOnLine(geometry::imageAxis(c), c.entry_px), scale);
  auto pixel = [&](double t) {
    Eigen::Vector2d const x = e + t * d;
    return cv::Point(static_cast<int>(std::lround(x.x())), static_cast<int>(std::lround(x.y())));
  };
  auto inside = [&](cv::Point q) { return q.x >= 0 && q.y >= 0 && q.x < labels.cols && q.y < labels.rows; };
  int i = 0;
  for (; i <= 6; ++i) {  // into the occluder
    cv::Point const q = pixel(i);
    if (!inside(q)) return false;
    if (labels.at<std::uint8_t>(q) == occluder) break;
  }
  if (i > 6) return false;
  for (int const end = i + 4 * std::max(labels.cols, labels.rows); i < end; ++i) {  // across it
    cv::Point const q = pixel(i);
    if (!inside(q)) return false;
    if (labels.at<std::uint8_t>(q) != occluder) break;
  }
  int low = 0;
  for (int k = 0; k < 4; ++k) {
    cv::Point const q = pixel(i + k);
    low += inside(q) && fov.mask.at<std::uint8_t>(q) && feature.at<std::uint8_t>(q) <= level;
  }
  return low >= 3;
}
}  // namespace

namespace {
// Instruments of one radius are about as wide where they cross, at about the same depth (a
// crossing seed's false pair, jaws beside a shaft, is a fraction of its width).
constexpr double kCrossingMinWidthRatio = 0.5;
// A contour's width at its tip over its width at its entry.
double widening(geometry::ApparentContour const& c) {
  Eigen::Vector3d const e = c.entry_px.homogeneous(), t = c.tip_px.homogeneous();
  return (c.lines[0].dot(t) + c.lines[1].dot(t)) / std::max(1e-9, c.lines[0].dot(e) + c.lines[1].dot(e));
}
// The strip an accepted shaft claims (processing px): between its lines widened by 2 px, from
// 2 px before its entry to 2 px beyond its tip.
std::vector<cv::Point> claimedStrip(geometry::ApparentContour const& c, int scale) {
  std::vector<cv::Point> strip;
  Eigen::Vector2d const ax = (c.tip_px - c.entry_px).normalized();
  for (Eigen::Vector2d const& e : {Eigen::Vector2d(c.entry_px - 2.0 * scale * ax), Eigen::Vector2d(c.tip_px + 2.0 * scale * ax)})
    for (int k = 0; k < 2; ++k) {
      Eigen::Vector2d const n = c.lines[k].head<2>();
      Eigen::Vector2d const f = geometry::footOnLine(c.lines[k], e) - n * (2.0 * scale);
      Eigen::Vector2d const ps = toProcessing(f, scale);
      strip.emplace_back(static_cast<int>(std::lround(ps.x())), static_cast<int>(std::lround(ps.y())));
    }
  std::swap(strip[2], strip[3]);
  return strip;
}
}  // namespace

ColourShaftDetector::ColourShaftDetector(SegmentationParams const& params) : params_(params), colour_(params.feature) {}

void ColourShaftDetector::setParams(SegmentationParams const& p) {
  if (p.feature.hue_origin_deg != params_.feature.hue_origin_deg || p.feature.gain != params_.feature.gain) colour_ = ColourFeature(p.feature);
  params_ = p;
  reset();  // (the memory's levels index the old threshold list)
}

void ColourShaftDetector::reset() {
  memory_.clear();
  contour_memory_.clear();
}

void ColourShaftDetector::shaftMoved(std::size_t i, cv::Point shift) {
  if (i < contour_memory_.size() && contour_memory_[i] < memory_.size()) memory_[contour_memory_[i]].entry += shift;
}

// One detection frame of the colour method: the feature, the seeds, and what the seeds' searches
// share (the result so far, the new seed memory, the crossing seeds' views).
struct ColourShaftDetector::FrameSearch {
  ColourShaftDetector& S;
  cv::Mat const& bgr;
  FieldOfView const& fov;
  int const scale;
  int const elapsed;  // frames since the last detection frame: the ages of the seed memory count frames
  SegmentationResult res;
  std::vector<Memory> memory_now;
  std::vector<std::size_t> contour_memory;  // per accepted contour: its seed's entry in memory_now
  bool all_confirmed = true;  // every shaft found was also found at the last detection (its seed's memory)
  bool have_gradient = false;
  double max_area = 0.0;
  // The stricter checks of re-sought side pairs (SeedSearch::resought).
  StripSearchParams resought_contrast;
  ContourLinesParams resought_contours;
  // Crossing seeds (addCrossingSeeds()): after the border's, seeds on the edge of an accepted shaft
  // that hides part of another; each is searched in the field of view less that shaft's pixels.
  int border_seeds = 0;
  std::deque<FieldOfView> occluded;  // per occluding shaft searched (stable references)
  std::vector<int> occluders;        // ... that shaft (index in res.contours)
  std::vector<int> seed_view;        // per crossing seed: its field of view in `occluded`
  std::vector<std::vector<cv::Point>> strips;  // per accepted contour: the strip it claimed (processing px)
  std::vector<int> strip_labels;               // ... and its label in grower_.labels()

  FrameSearch(ColourShaftDetector& s, DetectionFrame const& frame)
      : S(s), bgr(frame.bgr), fov(frame.fov), scale(frame.scale), elapsed(frame.elapsed) {
    res.scale = scale;
    S.colour_.compute(frame.small, S.raw_);
    sigmaFilter(S.raw_, S.filtered_, S.params_.sigma_radius, S.params_.sigma_delta);
    // Trocar images in processing pixels (homogeneous: some lie at infinity).
    std::vector<Eigen::Vector3d> t_small;
    for (auto const& t : frame.trocar_images) t_small.push_back(toProcessing(t, scale));
    res.seeds = findSeeds(S.filtered_, fov, S.params_.seeds, t_small);
    S.grower_.reset(S.filtered_, fov);
    max_area = S.params_.regions.max_area_fraction * frame.fov_area;
    resought_contrast = S.params_.strip;
    resought_contrast.max_full_res_ratio_matte = resought_contrast.max_full_res_ratio;
    resought_contours = S.params_.contours;
    resought_contours.min_entry_sine = std::max(resought_contours.min_entry_sine, S.params_.resought_min_entry_sine);
    border_seeds = static_cast<int>(res.seeds.size());
  }
  // A refused seed's run that is missing in this frame (a run near the seed threshold flickers)
  // keeps its memory while a full or strip search of it would not be due yet: when the run is
  // back it is not searched in full as a new seed.
  void carryMemory() {
    for (Memory const& m : S.memory_) {
      if (m.accepted || (S.fullSearchDue(m, m.width, elapsed) && S.stripSearchDue(&m, m.width, elapsed))) continue;
      bool const seen = std::any_of(memory_now.begin(), memory_now.end(),
                                    [&](Memory const& n) { return entryDistance(n.entry, m.entry) <= S.params_.level_memory_px; });
      if (seen) continue;
      Memory c = m;
      c.carried = true;
      c.age += elapsed;
      c.strip_age += elapsed;
      memory_now.push_back(std::move(c));
    }
  }
};

// One seed's search: grow at each threshold level, score each level's straight-line pair cheaply
// and refine the best in full until one is accepted; the strip search where every region leaked;
// side pairs sought again where they had no edges. In a video, a seed near last frame's entry of a
// shaft tries that shaft's level first and stops there if it scores as well as before; a seed near
// last frame's refused region only re-grows it (to claim it) until a full search is due
// (fullSearchDue(); its strip search: stripSearchDue()).
struct ColourShaftDetector::SeedSearch {
  struct Candidate {
    Region region;
    SideFit sides;
    double score;
    int level;
    bool resought = false;  // sides sought again (see reseek()) or from another seed's region
  };
  FrameSearch& F;
  ColourShaftDetector& S;
  SegmentationParams const& P;
  SegmentationResult& res;
  int const si;
  Seed const seed;
  bool const crossing;
  FieldOfView const& view;
  bool in_refused = false;
  int refused_region = -1;  // the refused region it lies in
  std::vector<int> T;       // the growth levels' thresholds (growthLevels())
  int strip_level = 0;
  Memory const* mem = nullptr;
  int mem_level = 0;  // last frame's level in this frame's list, which is longer on a dark border
  std::optional<Region> best;
  ContourFit best_fit;
  int best_level = -1;
  double best_score = 0.0;
  bool best_parallel = false;
  std::optional<StripCandidate> best_strip;
  ContourRejection why = ContourRejection::kTooFewPoints;
  bool strip_first = false, strip_run = false;
  std::optional<Region> smallest;
  int smallest_level = 0;
  std::vector<int> tried;  // levels grown so far
  // Candidates with a side found only as the stretch parallel to the other (fitSides(): a shaft
  // merged with a blob near its entry) come last, after the strip search.
  std::vector<Candidate> deferred;
  // Re-sought candidates, refined last of all: a candidate refused for sides without edges, or
  // for sides that diverge from the entry, has them sought again (fitSides(), SideSearch): the
  // shaft's boundary with a grey blob (gauze) has no edge in the image, its boundary with the
  // tissue beyond the blob has. A re-sought pair (and the region of another seed seen from this
  // one) is less certain than a pair followed from the entry: it must be less chromatic than the
  // tissue beside it as a strip with highlights must (matte or not: a pale tissue fold is matte),
  // enter clearly across the border, end inside the view, and is not remembered as a parallel
  // pair to try first next frame.
  std::vector<Candidate> resought;

  SeedSearch(FrameSearch& f, int i)
      : F(f), S(f.S), P(f.S.params_), res(f.res), si(i), seed(f.res.seeds[static_cast<std::size_t>(i)]), crossing(i >= f.border_seeds),
        view(crossing ? f.occluded[static_cast<std::size_t>(f.seed_view[static_cast<std::size_t>(i - f.border_seeds)])] : f.fov) {}

  // Whether the seed is searched: not inside a region already claimed, unless that region was
  // refused for another seed and this seed enters the view apart from it (a shaft merged with a
  // grey blob, a vessel or another instrument): then that region's sides are sought from this
  // entry and its strip search runs; nothing is grown again.
  bool due() {
    bool const claimed = S.grower_.claimed(seed.position);
    if (claimed && crossing) return false;
    if (claimed && P.strip.enabled && S.grower_.labels().at<std::uint8_t>(seed.position) == 255)
      for (std::size_t ri = 0; ri < res.regions.size() && !in_refused; ++ri) {
        Region const& r = res.regions[ri];
        in_refused = res.region_status[ri] != ContourRejection::kNone && r.box.contains(seed.position) &&
                     cv::pointPolygonTest(r.boundary, seed.position, false) >= 0 &&
                     !onOneBorderRun(r, F.fov, r.seed, seed.position, P.contours.border_margin);
        if (in_refused) refused_region = static_cast<int>(ri);
      }
    if (claimed && !in_refused) return false;
    // Growth levels (region_growing.h): lowered toward the seed's level on a dark border and
    // followed there by the absolute ones above them.
    GrowthLevels const levels = growthLevels(P.regions, seed.mean_value, seed.background);
    T = levels.thresholds;
    strip_level = levels.strip_level;
    mem = S.remembered(seed);
    mem_level = mem ? rememberedLevel(T, static_cast<int>(P.regions.thresholds.size()), mem->level, mem->threshold) : 0;
    return true;
  }

  void remember(Memory m) {
    m.threshold = T[m.level];
    F.memory_now.push_back(std::move(m));
  }

  // A refused seed: its region grown again at its level and claimed, until a full search is due
  // (backing off while it keeps giving no shaft). True when that was all.
  bool heldRefused() {
    if (in_refused || !mem || mem->accepted || S.fullSearchDue(*mem, seed.width, F.elapsed)) return false;
    // (a seed whose regions all leaked has none to claim)
    std::optional<Region> r = mem->grown ? S.grower_.grow(seed.position, T[mem_level], si) : std::nullopt;
    // (backed off beyond full_search_every: its region must be as it was, see fullSearchDue())
    bool const changed = mem->age + F.elapsed >= P.full_search_every && r && mem->area > 0 &&
                         std::abs(r->area - mem->area) > P.refused_area_change * std::max(r->area, mem->area);
    if (changed) return false;
    if (r) {
      res.regions.push_back(*r);
      res.region_status.push_back(mem->why);
      S.grower_.claim(*r, 255);
    }
    remember({seed.position, mem_level, 0.0, false, mem->why, mem->age + F.elapsed, mem->strip_age + F.elapsed, mem->strip_fails,
              seed.width, std::nullopt, mem->grown});
    F.memory_now.back().fails = mem->fails;
    F.memory_now.back().area = mem->area;  // (the last full search's: a slow change adds up)
    return true;
  }

  // The strip search (strip_search.h): the sides searched from the seed in the gradient.
  void tryStrip(StripCandidate const* previous) {
    if (!F.have_gradient) {
      cv::spatialGradient(S.filtered_, S.gx_, S.gy_, 3);  // both 3x3 Sobel derivatives in one pass (as cv::Sobel, half the time)
      S.rays_ = packRayField(S.gx_, S.gy_, F.fov);        // (one load per step of the ray walks)
      F.have_gradient = true;
    }
    ++res.strip_searches;
    auto sc = searchStrip(S.filtered_, S.rays_, F.fov, seed, strip_level, F.scale, P.strip, P.contours, previous);
    if (!sc) return;
    ContourFit f = refineStrip(*sc, F.fov, F.bgr, F.scale, P.strip, P.contours);
    if (f.contour) {
      AcrossSamples const across = acrossContour(F.bgr, *f.contour);
      if (!stripContrastFullRes(across, P.strip)) f.rejection = ContourRejection::kLowContrast;
      else if (mostlyGlare(across, P.contours)) f.rejection = ContourRejection::kGlare;
      if (f.rejection != ContourRejection::kNone) f.contour.reset();
    }
    if (!f.contour) {
      why = f.rejection;
      return;
    }
    best = sc->region;
    best_fit = std::move(f);
    best_level = static_cast<int>(P.regions.thresholds.size()) - 1;  // the strip level's index
    best_score = sc->score;
    best_strip = std::move(sc);
  }

  // The sides of `region` sought again (its pair from the entry had no edges or diverged, or none
  // was found in a region another seed grew): re-sought candidates. `fitted`: the region's
  // fitSides() (its chains are reused).
  void reseek(Region const& region, int level, SideFit const& fitted) {
    if (P.contours.min_parallel_side_ratio <= 0.0) return;
    for (SideFit& again : fitSidesEach(region, view, F.scale, P.contours,
                                       {SideSearch::kParallelFirst, SideSearch::kParallelSecond, SideSearch::kStretchPair}, &fitted)) {
      if (again.rejection != ContourRejection::kNone) continue;
      double const score = scoreSides(again, F.bgr, P.contours);
      if (score >= 0.0) resought.push_back({region, std::move(again), score, level, true});
    }
  }

  // The checks of a fitted contour beyond the contour fit's: contrast, tip, glare and widening for
  // a re-sought pair; width and continuation for a crossing shaft.
  ContourRejection check(geometry::ApparentContour const& c, Candidate const& cd) const {
    AcrossSamples const across = acrossContour(F.bgr, c);
    if (cd.resought && !stripContrastFullRes(across, F.resought_contrast)) return ContourRejection::kLowContrast;
    if (cd.resought && depthAt(view, toProcessing(c.tip_px, F.scale)) < P.resought_min_tip_depth_px) return ContourRejection::kTipOnBorder;
    if (mostlyGlare(across, P.contours)) return ContourRejection::kGlare;
    if (cd.resought && widening(c) > P.resought_max_widening) return ContourRejection::kWidens;
    if (!crossing) return ContourRejection::kNone;
    // A crossing shaft's part beyond the occluder: where they cross the two are at about the same
    // depth, and of the same radius, so about as wide (at least kCrossingMinWidthRatio of the
    // occluder); and it goes on on the occluder's other side.
    int const k = F.occluders[static_cast<std::size_t>(F.seed_view[static_cast<std::size_t>(si - F.border_seeds)])];
    geometry::ApparentContour const& o = res.contours[static_cast<std::size_t>(k)];
    Eigen::Vector3d const e = c.entry_px.homogeneous();
    Eigen::Vector3d const oe = geometry::footOnLine(geometry::imageAxis(o), c.entry_px).homogeneous();
    double const we = c.lines[0].dot(e) + c.lines[1].dot(e);
    if (we < kCrossingMinWidthRatio * (o.lines[0].dot(oe) + o.lines[1].dot(oe))) return ContourRejection::kTooThin;
    if (!continuesBeyond(c, S.grower_.labels(), F.strip_labels[static_cast<std::size_t>(k)], S.filtered_, F.fov, T[cd.level], F.scale))
      return ContourRejection::kNotContinued;
    return ContourRejection::kNone;
  }

  // Refines the candidates, best score first, until one is accepted.
  void refineCandidates(std::vector<Candidate>& cands) {
    std::sort(cands.begin(), cands.end(), [](Candidate const& a, Candidate const& b) { return a.score > b.score; });
    for (auto& cd : cands) {
      ContourFit f = refineContour(cd.sides, cd.region, view, F.bgr, F.scale, cd.resought ? F.resought_contours : P.contours);
      if (f.contour) {
        f.rejection = check(*f.contour, cd);
        if (f.rejection != ContourRejection::kNone) f.contour.reset();
      }
      if (f.contour) {
        best = std::move(cd.region);
        best_fit = std::move(f);
        best_level = cd.level;
        best_score = cd.score;
        best_parallel = cd.sides.parallel && !cd.resought;
        return;
      }
      why = f.rejection;
      if (f.rejection == ContourRejection::kWeakEdges && !cd.sides.parallel) reseek(cd.region, cd.level, cd.sides);
    }
  }

  // Grows at the given levels, scores each region's side pair, refines the best in full.
  // `tracked`: levels about last frame's (not ascending; stop at one as good as before).
  void tryLevels(std::vector<int> const& levels, bool tracked) {
    std::vector<Candidate> cands;
    for (int li : levels) {
      tried.push_back(li);
      auto r = S.grower_.grow(seed.position, T[li], si);
      if (!r) continue;
      if (r->area > F.max_area) {
        // Leaked into tissue: in a full search (levels ascending) higher thresholds only leak more.
        if (!tracked) break;
        continue;
      }
      if (!smallest || r->area < smallest->area) {
        smallest = r;
        smallest_level = li;
      }
      if (r->area < P.regions.min_area) continue;
      SideFit sf = fitSides(*r, view, F.scale, P.contours);
      double const score = scoreSides(sf, F.bgr, P.contours);
      if (score < 0.0) {
        why = sf.rejection != ContourRejection::kNone ? sf.rejection : ContourRejection::kWeakEdges;
        // Two straight sides from the entry that diverge: one follows a blob of the shaft's level
        // merged with it there (grey tissue, a leak); the shaft's own side is the stretch of that
        // chain parallel to the other.
        if (sf.rejection == ContourRejection::kNotParallel) reseek(*r, li, sf);
        continue;
      }
      // (not deferred for a shaft that was found so in the last frame: its level is tried first)
      bool const defer = sf.parallel && !(tracked && mem->parallel);
      // (a crossing seed's pair is checked as a re-sought one: it enters the view at another
      // shaft, not at the border)
      (defer ? deferred : cands).push_back({std::move(*r), std::move(sf), score, li, crossing});
      if (!defer && tracked && li == mem_level && score >= 0.85 * mem->score) break;  // as good as before
    }
    refineCandidates(cands);
  }

  // The refused region seen from this seed's border run: its two sides split at this entry, not
  // at the other seed's (a shaft merged with a blob that entered the view elsewhere and was
  // searched first: gauze reaching another border). A re-sought candidate; without a pair with
  // edges from this entry, its sides are sought again.
  void searchRefusedRegion() {
    Region r = res.regions[static_cast<std::size_t>(refused_region)];
    r.seed = seed.position;
    r.seed_index = si;
    if (r.area < P.regions.min_area) return;
    SideFit sf = fitSides(r, F.fov, F.scale, P.contours);
    double const score = scoreSides(sf, F.bgr, P.contours);
    int const level = std::min(static_cast<int>(std::lower_bound(T.begin(), T.end(), r.threshold) - T.begin()), static_cast<int>(T.size()) - 1);
    if (score < 0.0 && !sf.parallel) reseek(r, level, sf);  // no pair with edges from this entry
    if (score < 0.0) return;
    Candidate cd{std::move(r), std::move(sf), score, level, true};
    if (cd.sides.parallel) {
      deferred.push_back(std::move(cd));
    } else {
      std::vector<Candidate> cands{std::move(cd)};
      refineCandidates(cands);
    }
  }

  void search() {
    // A shaft found by the strip search in the last frame: searched about its sides first, but
    // every full_search_every frames its regions are grown first and that strip is the fallback
    // (a shaft found as a strip once is not held as a strip for good).
    strip_first = !crossing && mem && mem->accepted && mem->strip && P.strip.enabled && mem->age + F.elapsed < P.full_search_every;
    if (strip_first) tryStrip(&*mem->strip);
    std::vector<int> all(T.size());
    std::iota(all.begin(), all.end(), 0);
    if (in_refused) {
      ++res.full_searches;
      searchRefusedRegion();  // (then the strip search, below)
    } else if (!best && mem && mem->accepted) {
      std::vector<int> near;
      for (int d : {0, -1, 1})
        if (mem_level + d >= 0 && mem_level + d < static_cast<int>(T.size())) near.push_back(mem_level + d);
      tryLevels(near, true);
      // Lost about last frame's level: the full search now, over the levels not grown yet.
      if (!best) {
        ++res.full_searches;
        std::vector<int> rest;
        for (int li : all)
          if (std::find(tried.begin(), tried.end(), li) == tried.end()) rest.push_back(li);
        tryLevels(rest, false);
      }
    } else if (!best) {
      ++res.full_searches;
      tryLevels(all, false);
    }
    // The region leaked or split at every level: the shaft's sides searched from the seed in the
    // feature's gradient, once per seed. Not for a seed that is one only under the relaxed
    // threshold facing a trocar image: the strip search, the costliest step, found no shaft from
    // such a seed in any evaluation.
    strip_run = !best && !crossing && P.strip.enabled && seed.mean_value <= P.seeds.threshold && S.stripSearchDue(mem, seed.width, F.elapsed);
    if (strip_run) tryStrip(mem && mem->accepted && mem->strip && !strip_first ? &*mem->strip : nullptr);
    if (!best && !deferred.empty()) refineCandidates(deferred);
    while (!best && !resought.empty()) {  // (a re-sought pair is a parallel one: it re-seeks nothing)
      std::vector<Candidate> last = std::move(resought);
      resought.clear();
      refineCandidates(last);
    }
  }

  // The seed's memory, and the shaft found (claimed, reported) or the region refused (claimed).
  void conclude() {
    if (best) {
      // (a strip followed from the last frame's had no full search: its age goes on)
      int const age = strip_first && best_strip ? mem->age + F.elapsed : 0;
      remember({seed.position, best_level, best_score, true, ContourRejection::kNone, age, 0, 0, seed.width, best_strip});
      F.memory_now.back().parallel = best_parallel;
    }
    // A second detection of a shaft already found (a seed on its shadow, or a second seed on its
    // border run): the region is claimed, not reported. Its memory stays that of a shaft, so that
    // next frame this seed is searched again at once (the other seed may be gone by then).
    if (best && duplicatesAShaft(*best_fit.contour, res.contours)) {
      why = ContourRejection::kDuplicate;
      smallest = std::move(best);
      best.reset();
    }
    if (!best && why != ContourRejection::kDuplicate) {
      int const age = mem && !mem->accepted ? mem->strip_age : 0, fails = mem && !mem->accepted ? mem->strip_fails : 0;
      // (a seed that only had its strip searched has had no full search: due at once next time)
      remember({seed.position, smallest ? smallest_level : 0, 0.0, false, why, in_refused ? P.full_search_every : 0,
                strip_run ? 0 : age + F.elapsed, strip_run ? fails + 1 : fails, seed.width, std::nullopt, smallest.has_value()});
      F.memory_now.back().fails = mem && !mem->accepted && !in_refused ? mem->fails + 1 : 1;
      F.memory_now.back().area = smallest ? smallest->area : 0;
    }
    Region const* keep = best ? &*best : (smallest ? &*smallest : nullptr);
    if (!keep) return;
    res.regions.push_back(*keep);
    res.region_status.push_back(best ? ContourRejection::kNone : why);
    // Claimed either way, so the other seeds of this blob are skipped; an accepted shaft claims
    // only its strip (widened by 2 px), so a touching instrument's seed still grows.
    std::vector<cv::Point> const strip = best ? claimedStrip(*best_fit.contour, F.scale) : std::vector<cv::Point>{};
    S.grower_.claim(*keep, best ? static_cast<int>(res.regions.size()) : 255, strip);
    if (best) report(strip);
  }

  void report(std::vector<cv::Point> const& strip) {
    F.strips.push_back(strip);
    F.strip_labels.push_back(static_cast<int>(res.regions.size()));
    // (only the report is on the image axis: the claim and the checks keep the region's points)
    geometry::ApparentContour c = onImageAxis(*best_fit.contour);
    c.insertion_point_id = seed.insertion_point;
    res.contours.push_back(c);
    F.contour_memory.push_back(F.memory_now.size() - 1);  // this seed's memory (pushed by conclude())
    res.contour_regions.push_back(res.regions.size() - 1);  // its region (pushed by conclude())
    F.all_confirmed = F.all_confirmed && mem && mem->accepted;
    res.edges.push_back(best_fit.edges);
  }
};

SegmentationResult ColourShaftDetector::detect(DetectionFrame const& frame) {
  FrameSearch F(*this, frame);
  for (int si = 0;; ++si) {
    if (si == F.border_seeds && params_.crossing_seeds && !F.res.contours.empty()) addCrossingSeeds(F);
    if (si >= static_cast<int>(F.res.seeds.size())) break;
    if (static_cast<int>(F.res.contours.size()) >= params_.regions.max_regions) break;
    SeedSearch s(F, si);
    if (!s.due() || s.heldRefused()) continue;
    s.search();
    s.conclude();
  }
  // (a shaft found whole after a strip inside it was: the strip's seed came first)
  removeDuplicateShafts(F.res, F.contour_memory);
  locateTips(F.res, frame);
  labels_ = grower_.labels();
  F.carryMemory();
  memory_ = std::move(F.memory_now);
  contour_memory_ = std::move(F.contour_memory);
  // Only shafts confirmed by two detections in a row are tracked: a new one (or a tissue band
  // found in some frames only) makes the next frame a detection frame too, so that a false shaft
  // is not held for detect_every frames.
  confirmed_ = F.all_confirmed;
  return std::move(F.res);
}

namespace {
// Which accepted shafts' strips (labels `strip_labels` in `L`) a refused region touches.
std::vector<bool> touchedByRefused(SegmentationResult const& res, cv::Mat const& L, std::vector<int> const& strip_labels) {
  std::vector<bool> touched(strip_labels.size(), false);
  for (std::size_t ri = 0; ri < res.regions.size(); ++ri) {
    if (res.region_status[ri] == ContourRejection::kNone) continue;
    for (cv::Point const& q : res.regions[ri].boundary)
      for (cv::Point const d : {cv::Point(1, 0), cv::Point(-1, 0), cv::Point(0, 1), cv::Point(0, -1)}) {
        cv::Point const r = q + d;
        if (r.x < 0 || r.y < 0 || r.x >= L.cols || r.y >= L.rows) continue;
        int const l = L.at<std::uint8_t>(r);
        for (std::size_t k = 0; k < strip_labels.size(); ++k) touched[k] = touched[k] || (l != 0 && l == strip_labels[k]);
      }
  }
  return touched;
}

// The crossing seeds along one side of a strip, from corner pa to pb, 1.5 px outside it (away
// from po, a corner of the other side): runs of the feature at or below the seed threshold, at
// least min_width long and at most half the side, unclaimed and margin px inside the view.
void seedsAlongSide(Eigen::Vector2d const& pa, Eigen::Vector2d const& pb, Eigen::Vector2d const& po, cv::Mat const& feature,
                    FieldOfView const& fov, RegionGrower const& grower, SeedSearchParams const& p, int margin, std::vector<Seed>& found) {
  double const len = (pb - pa).norm();
  if (len < 2.0 * p.min_width) return;
  Eigen::Vector2d const u = (pb - pa) / len;
  Eigen::Vector2d nrm(-u.y(), u.x());
  if (nrm.dot(po - pa) > 0.0) nrm = -nrm;  // away from the other side
  int const n = static_cast<int>(len);
  std::vector<int> value(static_cast<std::size_t>(n + 1), -1);  // -1: not searched there
  std::vector<cv::Point> at(static_cast<std::size_t>(n + 1));
  std::vector<float> valid;
  for (int i = 0; i <= n; ++i) {
    Eigen::Vector2d const x = pa + i * u + 1.5 * nrm;
    cv::Point const q(static_cast<int>(std::lround(x.x())), static_cast<int>(std::lround(x.y())));
    if (q.x < 0 || q.y < 0 || q.x >= feature.cols || q.y >= feature.rows || !fov.mask.at<std::uint8_t>(q) || fov.depth.at<float>(q) < margin)
      continue;
    at[i] = q;
    value[i] = feature.at<std::uint8_t>(q);
    valid.push_back(static_cast<float>(value[i]));
    if (grower.claimed(q)) value[i] = 256;  // searched, not a seed
  }
  if (valid.empty()) return;
  std::nth_element(valid.begin(), valid.begin() + valid.size() * 3 / 4, valid.end());
  float const background = valid[valid.size() * 3 / 4];  // the tissue's level beside the shaft
  for (int i = 0; i <= n;) {
    if (value[i] < 0 || value[i] > p.threshold) {
      ++i;
      continue;
    }
    int j = i;
    double sum = 0.0;
    while (j <= n && value[j] >= 0 && value[j] <= p.threshold) sum += value[j++];
    int const w = j - i;
    if (w >= p.min_width && w <= n / 2) {
      Seed sd;
      sd.position = at[(i + j - 1) / 2];
      sd.width = w;
      sd.mean_value = static_cast<float>(sum / w);
      sd.background = background;
      found.push_back(sd);
    }
    i = j;
  }
}

// The view less a shaft's pixels, whose edge becomes its border (depth: distance to either).
FieldOfView viewLessShaft(FieldOfView const& fov, cv::Mat const& shaft_pixels) {
  FieldOfView v;
  v.mask = fov.mask.clone();
  // (dilated by 1 px: the claimed strip's rasterised edge is jagged, and fitSides() looks for
  // the border at border_margin px straight across; a boundary point on a step of it was
  // missed, which split the entry)
  cv::Mat shaft;
  cv::dilate(shaft_pixels, shaft, cv::Mat());
  v.mask.setTo(0, shaft);
  cv::Mat dist;
  cv::distanceTransform(~shaft, dist, cv::DIST_L2, 3);
  v.depth = cv::min(fov.depth, dist);
  v.border = fov.border;  // (the border's seeds' path: crossing seeds are not searched along it)
  v.bounds = fov.bounds;
  v.circular = fov.circular;
  v.centre = fov.centre;
  return v;
}
}  // namespace

// Crossing seeds ([Doignon07] Sec. 3's 1-D search, along an accepted shaft's edge instead of the
// border). Only about an accepted shaft that a refused region touches: the part of a crossing
// shaft on the border's side of it, refused (merged with a blob, or too short alone), is the
// sign. Seeds along each side of its strip (seedsAlongSide()), neither claimed nor at the border
// (the border's own seeds). Their field of view: the view less the shaft's claimed pixels (its
// edge is their border: fitSides() takes the region's boundary along it for the entry, and the
// entry checks measure against it).
void ColourShaftDetector::addCrossingSeeds(FrameSearch& F) const {
  cv::Mat const& L = grower_.labels();
  std::vector<bool> const touched = touchedByRefused(F.res, L, F.strip_labels);
  int const margin = params_.contours.border_margin + 2;
  for (std::size_t k = 0; k < F.strips.size(); ++k) {
    std::vector<cv::Point> const& s = F.strips[k];
    if (!touched[k] || s.size() != 4) continue;
    std::vector<Seed> found;
    // The strip's corners: entry and tip feet of line 0 (0, 3) and of line 1 (1, 2).
    for (auto const& [a, b, o] : {std::array<int, 3>{0, 3, 1}, std::array<int, 3>{1, 2, 0}})
      seedsAlongSide(Eigen::Vector2d(s[a].x, s[a].y), Eigen::Vector2d(s[b].x, s[b].y), Eigen::Vector2d(s[o].x, s[o].y), filtered_,
                     F.fov, grower_, params_.seeds, margin, found);
    if (found.empty()) continue;
    F.occluded.push_back(viewLessShaft(F.fov, L == F.strip_labels[k]));
    F.occluders.push_back(static_cast<int>(k));
    for (Seed const& sd : found) {
      F.res.seeds.push_back(sd);
      F.seed_view.push_back(static_cast<int>(F.occluded.size()) - 1);
    }
  }
}

// The memory of the nearest of last frame's seeds within level_memory_px.
ColourShaftDetector::Memory const* ColourShaftDetector::remembered(Seed const& seed) const {
  Memory const* best = nullptr;
  int best_d = 0;
  for (auto const& m : memory_) {
    int const d = entryDistance(m.entry, seed.position);
    if (d <= params_.level_memory_px && (!best || d < best_d)) {
      best = &m;
      best_d = d;
    }
  }
  return best;
}

// How far apart two seeds' entries are for the seed memory (processing px, city block).
int ColourShaftDetector::entryDistance(cv::Point a, cv::Point b) { return std::abs(a.x - b.x) + std::abs(a.y - b.y); }

// Whether a search that gave nothing `fails` times in a row is due, `age` frames after the last:
// every `every` frames, the interval doubling per failure after the first, up to `max_every`.
namespace {
bool backedOffDue(int age, int fails, int every, int max_every) {
  every = std::max(1, every);
  max_every = std::max(every, max_every);
  for (int k = 1; k < fails && every < max_every; ++k) every *= 2;
  return age >= std::min(every, max_every);
}
}  // namespace

// Whether a seed's border run is now of another width than its memory's (by more than a quarter):
// something entered or left there.
bool ColourShaftDetector::runChanged(Memory const& m, int width) { return std::abs(width - m.width) * 4 > std::max(width, m.width); }

// A refused seed's full search (growth at every level): every full_search_every frames, and
// less and less often while it keeps giving no shaft (the interval doubles per failure up to
// full_search_max_every frames), unless its run changed width (or its region its area:
// process()). A memory kept over a frame without its run (carried) holds only for a run of its
// width.
bool ColourShaftDetector::fullSearchDue(Memory const& m, int width, int elapsed) const {
  int const age = m.age + elapsed;
  if (runChanged(m, width) && (m.carried || age >= params_.full_search_every)) return true;
  return backedOffDue(age, m.fails, params_.full_search_every, params_.full_search_max_every);
}

// The strip search of a seed that keeps giving no shaft (it costs as much as the rest of a
// frame) runs at its full searches, but the interval doubles per failure up to
// strip_search_max_every frames. Always for a new seed, a lost shaft, or a run that changed width.
bool ColourShaftDetector::stripSearchDue(Memory const* m, int width, int elapsed) const {
  if (!m || m->accepted || m->strip_fails == 0) return true;
  if (runChanged(*m, width)) return true;
  return backedOffDue(m->strip_age + elapsed, m->strip_fails, params_.full_search_every, params_.strip_search_max_every);
}

}  // namespace endo_guidance::perception
