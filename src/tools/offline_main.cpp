// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
//
// endo_guidance_offline: the whole per-frame pipeline (segmentation -> contour lines -> cylinder
// pose -> insertion points -> attachment) on image files, image directories, videos or bags,
// without a ROS master. One JSON object per frame (README, "Offline program").
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cv_bridge/cv_bridge.h>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "endo_guidance/perception/learned_shaft_detector.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance_git_revision.h"
#include "endo_guidance/io/yaml_config.h"
#include "frame_sources.h"

namespace fs = std::filesystem;
using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::pipeline;
namespace tools = endo_guidance::tools;
namespace io = endo_guidance::io;

namespace {

void usage(std::FILE* f) {
  std::fprintf(f,
               "usage: endo_guidance_offline [--camera CAMERA.yaml] --radius METRES [--params PARAMS.yaml]\n"
               "                             [--output OUT.jsonl] [--overlay DIR|VIDEO] [--image-topic TOPIC]\n"
               "                             [--fps HZ] [--truth TRUTH.yaml] [--independent] [--quiet]\n"
               "                             [--detector colour|learned] [--model MODEL.yaml] [--report DIR] INPUT...\n"
               "  INPUT: image files, a directory of images (sorted by name), a video file, or a bag\n"
               "         (--image-topic; its camera_info is used when present).\n"
               "  CAMERA.yaml: ROS camera_info YAML (camera_calibration_parsers format); distorted\n"
               "         images are segmented as they are and the contours given in rectified pixels.\n"
               "  --output: one JSON object per frame (default: standard output).\n"
               "  --overlay: a directory (one PNG per frame) or a video file (.avi/.mp4/.mkv).\n"
               "  --fps: time stamps of image files, and of a video without a frame rate (default 25).\n"
               "  --independent: each frame on its own (unrelated stills): the pipeline forgets every\n"
               "         earlier frame (seed levels, tracks, insertion points) before it; by default the\n"
               "         frames are one video, in order.\n"
               "  --truth: YAML 'trocars: [[x, y, z], ...]' (metres, camera frame): errors printed at the end.\n"
               "  --detector, --model: segmentation/detector and segmentation/learned_model (over --params).\n"
               "  --report: a run report in DIR: index.html with plots (detections over time, each trocar\n"
               "         converging with its 1-sigma band, the imaged axes in (theta, rho), the worst frames'\n"
               "         overlays, parameters and versions), frames.jsonl and run.yaml (docs/report.md).\n");
}

bool isImage(fs::path const& p) {
  std::string e = p.extension().string();
  std::transform(e.begin(), e.end(), e.begin(), ::tolower);
  return e == ".png" || e == ".jpg" || e == ".jpeg" || e == ".bmp" || e == ".tif" || e == ".tiff" || e == ".ppm";
}

// ------------------------------------------------------------------ JSON
std::string num(double v) {
  if (!std::isfinite(v)) return "null";  // never NaN in the output
  char b[32];
  std::snprintf(b, sizeof b, "%.9g", v);
  return b;
}
// Seconds with 9 decimals: a bag's stamps count from the epoch, where %.9g kept only 0.1 s (a
// double holds them to about 0.2 us).
std::string stampNum(double v) {
  if (!std::isfinite(v)) return "null";
  char b[40];
  std::snprintf(b, sizeof b, "%.9f", v);
  return b;
}
std::string vec(Eigen::VectorXd const& v) {
  std::string s = "[";
  for (int i = 0; i < v.size(); ++i) s += (i ? "," : "") + num(v(i));
  return s + "]";
}
std::string str(std::string const& s) {
  std::string o = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') o += '\\';
    if (static_cast<unsigned char>(c) < 0x20) {
      char b[8];
      std::snprintf(b, sizeof b, "\\u%04x", c);
      o += b;
      continue;
    }
    o += c;
  }
  return o + "\"";
}

std::string frameJson(long k, tools::Frame const& f, PipelineOutput const& out) {
  std::ostringstream j;
  j << "{\"frame\": " << k << ", \"source\": " << str(f.source) << ", \"stamp\": " << stampNum(f.stamp);
  if (!out.error.empty()) {
    j << ", \"error\": " << str(out.error) << "}";
    return j.str();
  }
  j << ", \"instruments\": [";
  for (std::size_t i = 0; i < out.instruments.size(); ++i) {
    auto const& o = out.instruments[i];
    j << (i ? ", " : "") << "{\"track\": " << o.track << ", \"insertion_point\": " << o.insertion_point
      << ", \"contours\": [" << vec(o.contour.lines[0]) << ", " << vec(o.contour.lines[1]) << "]"
      << ", \"direction\": " << vec(o.pose.axis.direction()) << ", \"moment\": " << vec(o.pose.axis.moment())
      << ", \"residual_px\": " << num(o.contour.residual_px) << ", \"entry_px\": " << vec(o.contour.entry_px)
      << ", \"tip_px\": " << vec(o.contour.tip_px)
      << ", \"through_insertion_point\": ";
    if (o.constrained)
      j << "{\"direction\": " << vec(o.constrained->pose.axis.direction()) << ", \"moment\": " << vec(o.constrained->pose.axis.moment())
        << ", \"chi2\": " << num(o.constrained->chi2) << "}";
    else
      j << "null";
    j << "}";
  }
  j << "], \"insertion_points\": [";
  for (std::size_t i = 0; i < out.insertion_points.size(); ++i) {
    auto const& p = out.insertion_points[i];
    std::string pixel = "null";
    if (std::abs(p.image_point.z()) > 1e-12) pixel = vec(Eigen::Vector2d(p.image_point.head<2>() / p.image_point.z()));
    // Row-major 3x3, m^2, as InsertionPoint.msg (null entries where it is unbounded).
    Eigen::Matrix<double, 3, 3, Eigen::RowMajor> const cov = p.estimate.covariance;
    j << (i ? ", " : "") << "{\"id\": " << p.id << ", \"position\": " << vec(p.estimate.position) << ", \"pixel\": " << pixel
      << ", \"views\": " << p.estimate.views << ", \"rms_m\": " << num(p.estimate.rms_distance)
      << ", \"conditioning\": " << num(p.estimate.conditioning)
      << ", \"well_conditioned\": " << (p.well_conditioned ? "true" : "false")
      << ", \"located\": " << (p.located ? "true" : "false")
      << ", \"covariance\": " << vec(Eigen::Map<Eigen::Matrix<double, 9, 1> const>(cov.data())) << "}";
  }
  j << "], \"latency_ms\": " << num(out.latency_ms) << "}";
  return j.str();
}

// ------------------------------------------------------------------ report
constexpr std::size_t kWorstFrames = 6;

struct WorstFrame {
  double residual_px;
  long frame;
  std::string source;
  cv::Mat overlay;
};

std::string yamlStr(std::string const& s) { return str(s); }  // a JSON string is a YAML scalar

// run.yaml: what the report states about the run (inputs, camera, parameters, versions).
void writeRunYaml(fs::path const& dir, std::vector<std::string> const& inputs, Eigen::Matrix3d const& K, cv::Size size,
                  PipelineParams const& params, std::string const& params_path, long frames, long rejected, double seconds) {
  std::ofstream y(dir / "run.yaml");
  if (!y) throw std::runtime_error("cannot write '" + (dir / "run.yaml").string() + "'");
  y << "program: endo_guidance_offline\n"
    << "endo_guidance_version: " << ENDO_GUIDANCE_VERSION << "\n"
    << "git_revision: " << yamlStr(ENDO_GUIDANCE_GIT_REVISION) << "\n"
    << "opencv_version: " << yamlStr(CV_VERSION) << "\n"
    << "eigen_version: " << EIGEN_WORLD_VERSION << "." << EIGEN_MAJOR_VERSION << "." << EIGEN_MINOR_VERSION << "\n"
    << "inputs:\n";
  for (auto const& in : inputs) y << "  - " << yamlStr(fs::absolute(in).string()) << "\n";
  y << "image_size: [" << size.width << ", " << size.height << "]\n"
    << "camera_matrix: [" << K(0, 0) << ", " << K(0, 1) << ", " << K(0, 2) << ", " << K(1, 0) << ", " << K(1, 1) << ", " << K(1, 2)
    << ", " << K(2, 0) << ", " << K(2, 1) << ", " << K(2, 2) << "]\n"
    << "parameters_file: " << yamlStr(params_path.empty() ? "(built-in defaults, as config/pipeline.yaml)" : fs::absolute(params_path).string()) << "\n"
    << "radius_m: " << params.radius << "\n"
    << "detector: " << io::toString(params.segmentation.detector) << "\n";
  if (params.segmentation.detector == SegmentationParams::Detector::kLearned)
    y << "learned_model: " << yamlStr(params.segmentation.learned.model.empty() ? defaultShaftModel() : params.segmentation.learned.model)
      << "\n";
  y << "frames: " << frames << "\nrejected_frames: " << rejected << "\nprocessing_seconds: " << seconds << "\n";
}

// The plots and index.html come from scripts/run_report.py (matplotlib).
void makeReport(fs::path const& dir) {
  std::string const script = std::string(ENDO_GUIDANCE_SCRIPTS_DIR) + "/run_report.py";
  std::string const d = dir.string();
  char const* argv[] = {"/usr/bin/python3", script.c_str(), d.c_str(), nullptr};
  pid_t pid;
  if (posix_spawn(&pid, argv[0], nullptr, nullptr, const_cast<char* const*>(argv), environ) != 0)
    throw std::runtime_error("report: cannot run /usr/bin/python3 " + script);
  int status = 0;
  waitpid(pid, &status, 0);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) throw std::runtime_error("report: " + script + " failed (its message above)");
}

}  // namespace

int main(int argc, char** argv) {
  std::string camera_path, params_path, output, overlay, topic = "/camera/image_raw", truth_path, detector, model, report;
  double radius = -1.0, fps = 25.0;
  bool quiet = false, independent = false;
  std::vector<std::string> inputs;
  for (int i = 1; i < argc; ++i) {
    std::string const a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "endo_guidance_offline: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--camera") camera_path = value();
    else if (a == "--radius") radius = std::atof(value().c_str());
    else if (a == "--params") params_path = value();
    else if (a == "--detector") detector = value();
    else if (a == "--model") model = value();
    else if (a == "--output") output = value();
    else if (a == "--overlay") overlay = value();
    else if (a == "--image-topic") topic = value();
    else if (a == "--fps") fps = std::atof(value().c_str());
    else if (a == "--truth") truth_path = value();
    else if (a == "--report") report = value();
    else if (a == "--quiet") quiet = true;
    else if (a == "--independent") independent = true;
    else if (a == "-h" || a == "--help") {
      usage(stdout);
      return 0;
    } else if (!a.empty() && a[0] == '-') {
      std::fprintf(stderr, "endo_guidance_offline: unknown option '%s'\n", a.c_str());
      usage(stderr);
      return 2;
    } else {
      inputs.push_back(a);
    }
  }
  if (inputs.empty() || !(fps > 0.0)) {
    usage(stderr);
    return 2;
  }
  try {
    PipelineParams params;
    if (!params_path.empty()) io::loadPipelineYaml(params_path, params);
    if (!detector.empty()) params.segmentation.detector = io::detectorFromString(detector);
    if (!model.empty()) params.segmentation.learned.model = model;
    if (radius > 0.0) params.radius = radius;
    else if (params_path.empty()) throw std::runtime_error("--radius METRES is required (e.g. 0.004 for 8 mm shafts)");
    if (!(params.radius > 0.0) || params.radius > 0.05) throw std::runtime_error("radius must be in (0, 0.05] m");

    // Sources, in order.
    std::vector<std::unique_ptr<tools::Source>> sources;
    std::vector<std::string> images;
    auto flushImages = [&]() {
      if (!images.empty()) sources.push_back(tools::openImageFiles(images, fps));
      images.clear();
    };
    for (auto const& in : inputs) {
      fs::path const p(in);
      if (fs::is_directory(p)) {
        std::vector<std::string> v;
        for (auto const& e : fs::directory_iterator(p))
          if (e.is_regular_file() && isImage(e.path())) v.push_back(e.path().string());
        std::sort(v.begin(), v.end());
        if (v.empty()) throw std::runtime_error("directory '" + in + "' holds no images");
        images.insert(images.end(), v.begin(), v.end());
      } else if (isImage(p)) {
        images.push_back(in);
      } else if (!fs::exists(p)) {
        throw std::runtime_error("input '" + in + "' does not exist");
      } else if (p.extension() == ".bag") {
        flushImages();
        sources.push_back(tools::openBag(in, topic));
      } else {
        flushImages();
        sources.push_back(tools::openVideo(in, fps));
      }
    }
    flushImages();

    std::optional<io::CameraModel> cam;
    for (auto const& s : sources)
      if (auto c = s->camera()) cam = c;
    if (!cam && camera_path.empty()) throw std::runtime_error("--camera CAMERA.yaml is required (no camera_info in the input)");
    if (!camera_path.empty() && !cam) cam = io::loadCameraYaml(camera_path);

    // Lens distortion: the images are segmented as they are, and each contour refitted to its
    // rectified edge points (as the Segmentation nodelet does); poses and output in the rectified camera.
    Eigen::Matrix3d const K = cam->rectifiedK();
    PointRectifier rectify;
    if (cam->hasDistortion()) {
      cv::Matx33d Kc, Kn;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) Kc(r, c) = cam->K(r, c), Kn(r, c) = K(r, c);
      rectify = pointRectifier(Kc, cv::Mat(cam->D, true).reshape(1, 1), cv::Matx33d::eye(), Kn, cv::Size(cam->width, cam->height));
    }
    Pipeline pipe(K, cv::Size(cam->width, cam->height), params, rectify);

    std::ofstream file, report_file;
    std::ostream* js = &std::cout;
    if (!output.empty()) {
      file.open(output);
      if (!file) throw std::runtime_error("cannot write '" + output + "'");
      js = &file;
    }
    std::vector<WorstFrame> worst;  // the kWorstFrames frames of largest line residual
    if (!report.empty()) {
      fs::create_directories(fs::path(report) / "worst");
      for (auto const& e : fs::directory_iterator(fs::path(report) / "worst")) fs::remove(e.path());
      report_file.open(fs::path(report) / "frames.jsonl");
      if (!report_file) throw std::runtime_error("cannot write '" + report + "/frames.jsonl'");
    }
    cv::VideoWriter writer;
    bool const overlay_video = !overlay.empty() && (fs::path(overlay).extension() == ".avi" ||
                                                    fs::path(overlay).extension() == ".mp4" || fs::path(overlay).extension() == ".mkv");
    if (!overlay.empty() && !overlay_video) fs::create_directories(overlay);

    long total = 0;
    for (auto const& s : sources) total += std::max(0L, s->size());
    bool const tty = !quiet && isatty(2);
    long k = 0, bad = 0;
    auto const start = std::chrono::steady_clock::now();
    PipelineOutput last;
    for (auto const& s : sources) {
      tools::Frame f;
      while (s->next(f)) {
        PipelineOutput out;
        if (!f.error.empty()) {
          out.error = f.error;
        } else {
          cv::Mat const& img = f.image;
          if (independent) pipe.reset();
          out = pipe.process(img, f.stamp);
          if (out.error.empty()) last = out;
          double residual = -1.0;
          for (auto const& o : out.instruments) residual = std::max(residual, o.contour.residual_px);
          bool const is_worst = !report.empty() && residual >= 0.0 &&
                                (worst.size() < kWorstFrames || residual > worst.back().residual_px);
          if ((!overlay.empty() || is_worst) && out.error.empty()) {
            cv::Mat ov = img.clone();
            std::vector<Eigen::Vector3d> ti;
            for (auto const& p : out.insertion_points) ti.push_back(p.image_point);
            drawSegmentationOverlay(ov, out.segmentation, ti);
            if (is_worst) {
              if (worst.size() == kWorstFrames) worst.pop_back();
              worst.push_back({residual, k, f.source, ov.clone()});
              std::sort(worst.begin(), worst.end(), [](auto const& a, auto const& b) { return a.residual_px > b.residual_px; });
            }
            if (overlay.empty()) {
            } else if (overlay_video) {
              if (!writer.isOpened())
                writer.open(overlay, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), fps, ov.size());
              writer.write(ov);
            } else {
              char name[32];
              std::snprintf(name, sizeof name, "%06ld.png", k);
              cv::imwrite((fs::path(overlay) / name).string(), ov);
            }
          }
        }
        if (!out.error.empty()) {
          ++bad;
          std::fprintf(stderr, "%sframe %ld (%s): %s -- skipped\n", tty ? "\n" : "", k, f.source.c_str(), out.error.c_str());
        }
        std::string const line = frameJson(k, f, out);
        if (report.empty() || !output.empty()) *js << line << "\n";
        if (!report.empty()) report_file << line << "\n";
        ++k;
        if (tty) {
          double const el = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
          int const w = 30, done = total > 0 ? static_cast<int>(w * std::min(1.0, static_cast<double>(k) / total)) : 0;
          std::fprintf(stderr, "\r[%s%s] %ld/%s frames  %.1f fps", std::string(done, '#').c_str(), std::string(w - done, ' ').c_str(),
                       k, total > 0 ? std::to_string(total).c_str() : "?", k / std::max(el, 1e-9));
        }
      }
    }
    if (tty) std::fprintf(stderr, "\n");
    js->flush();
    if (!report.empty()) {
      report_file.close();
      double const seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      writeRunYaml(report, inputs, K, cv::Size(cam->width, cam->height), params, params_path, k, bad, seconds);
      std::ofstream w(fs::path(report) / "worst" / "worst.yaml");
      for (auto const& x : worst) {
        char name[40];
        std::snprintf(name, sizeof name, "frame_%06ld.png", x.frame);
        cv::imwrite((fs::path(report) / "worst" / name).string(), x.overlay);
        w << "- {frame: " << x.frame << ", source: " << yamlStr(x.source) << ", residual_px: " << x.residual_px << ", image: " << name
          << "}\n";
      }
      w.close();
      makeReport(report);
      if (!quiet) std::fprintf(stderr, "report: %s\n", (fs::absolute(report) / "index.html").c_str());
    }
    if (!quiet) {
      std::fprintf(stderr, "%ld frames (%ld rejected); insertion points:\n", k, bad);
      std::vector<Eigen::Vector3d> truth;
      if (!truth_path.empty()) {
        YAML::Node const t = YAML::LoadFile(truth_path);
        for (auto const& q : t["trocars"]) {
          auto const v = q.as<std::vector<double>>();
          if (v.size() == 3) truth.emplace_back(v[0], v[1], v[2]);
        }
      }
      for (auto const& p : last.insertion_points) {
        Eigen::Vector3d const& x = p.estimate.position;
        double const sigma = p.estimate.longestSigma();
        std::fprintf(stderr, "  id %d: (%.1f, %.1f, %.1f) mm, %zu views, rms %.2f mm, spread %.1f deg, sigma %.2f mm%s", p.id, x.x() * 1e3,
                     x.y() * 1e3, x.z() * 1e3, p.estimate.views, p.estimate.rms_distance * 1e3,
                     std::asin(std::min(1.0, p.estimate.conditioning)) * 180.0 / M_PI, sigma * 1e3,
                     !p.well_conditioned ? " (ill-conditioned)" : p.located ? "" : " (not located yet)");
        if (!truth.empty()) {
          double best = 1e9;
          for (auto const& t : truth) best = std::min(best, (t - x).norm());
          std::fprintf(stderr, "; nearest true trocar %.2f mm away", best * 1e3);
        }
        std::fprintf(stderr, "\n");
      }
      if (!truth.empty())
        for (std::size_t i = 0; i < truth.size(); ++i) {
          double best = 1e9;
          for (auto const& p : last.insertion_points) best = std::min(best, (truth[i] - p.estimate.position).norm());
          std::fprintf(stderr, "  true trocar %zu (%.1f, %.1f, %.1f) mm: %s\n", i, truth[i].x() * 1e3, truth[i].y() * 1e3,
                       truth[i].z() * 1e3, best < 1.0 ? ("estimated within " + std::to_string(best * 1e3).substr(0, 5) + " mm").c_str() : "not found");
        }
    }
  } catch (std::exception const& e) {
    std::fprintf(stderr, "endo_guidance_offline: %s\n", e.what());
    return 1;
  }
  return 0;
}
