#include "eval/reference.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>

#include "eval/metrics.hpp"
#include "gpu/hash.hpp"
#include "render/output.hpp"
#include "render/run.hpp"
#include "scene/animation.hpp"

namespace haze::eval {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// Holds an flock on `path` for the scope: shards of one sweep must not render the same reference twice.
class FileLock {
 public:
  explicit FileLock(const std::string& path) {
    fd_ = ::open(path.c_str(), O_RDWR | O_CREAT, 0644);
    if (fd_ < 0)
      throw render::Error(fmt::format("cannot create lock file {}; choose a writable --out", path));
    ::flock(fd_, LOCK_EX);
  }
  ~FileLock() {
    ::flock(fd_, LOCK_UN);
    ::close(fd_);
  }
  FileLock(const FileLock&) = delete;
  FileLock& operator=(const FileLock&) = delete;

 private:
  int fd_ = -1;
};

// Content hash of a file, remembered by path, size and modification time: a sweep asks for the same
// (possibly large) .vdb at every run.
std::string file_hash(const std::string& path) {
  static std::mutex mutex;
  static std::map<std::string, std::pair<std::string, std::string>> known;  // path -> (stamp, hash)
  std::error_code ec;
  const auto size = fs::file_size(path, ec);
  if (ec)
    throw render::Error(fmt::format("cannot read {} for the reference key; check that it exists", path));
  const std::string stamp =
      fmt::format("{}:{}", size, fs::last_write_time(path, ec).time_since_epoch().count());
  std::lock_guard lock(mutex);
  if (auto it = known.find(path); it != known.end() && it->second.first == stamp) return it->second.second;
  std::ifstream f(path, std::ios::binary);
  if (!f)
    throw render::Error(fmt::format("cannot read {} for the reference key; check that it exists", path));
  uint64_t h = gpu::kFnv64Basis;
  std::vector<char> buf(1 << 20);
  while (f) {
    f.read(buf.data(), std::streamsize(buf.size()));
    h = gpu::fnv1a64(h, buf.data(), size_t(f.gcount()));
  }
  std::string hash = fmt::format("{:016x}", h);
  known[path] = {stamp, hash};
  return hash;
}

// Every layer of `img`, and for each denoised layer its noisy stand-in under the denoised name: a converged
// image has no noise left to remove, so what a denoiser aims for is the noisy layer's converged value.
void write_reference_frame(const std::string& path, const render::Image& img) {
  auto planes = render::exr_planes(img);
  std::vector<std::pair<std::string, const std::vector<float>*>> channels;
  for (const auto& [name, plane] : planes) channels.emplace_back(name, &plane);
  for (const auto& [denoised, noisy] : kDenoisedStandIns)
    for (const auto& [name, plane] : planes) {
      const size_t dot = name.rfind('.');
      const std::string layer = dot == std::string::npos ? "" : name.substr(0, dot);
      if (layer == noisy) channels.emplace_back(denoised + "." + name.substr(dot + 1), &plane);
    }
  render::write_exr_channels(path, img.width, img.height, channels);
}

}  // namespace

std::string hash_key(std::string_view bytes) {
  return fmt::format("{:016x}", gpu::fnv1a64(gpu::kFnv64Basis, bytes.data(), bytes.size()));
}

json ReferenceOptions::to_json() const {
  return {{"target", target}, {"quantile", quantile}, {"min_spp", min_spp}, {"max_spp", max_spp}};
}

ReferenceOptions reference_options_from_json(const json& j, const std::string& origin) {
  ReferenceOptions o;
  if (!j.is_object())
    throw render::Error(fmt::format("{}: expected an object {{\"target\": 0.01, ...}}", origin));
  for (const auto& item : j.items()) {
    const std::string& k = item.key();  // named, not bound: clang 14 lambdas cannot capture bindings
    const json& v = item.value();
    const std::string key = fmt::format("{}.{}", origin, k);
    auto number = [&](double lo, double hi) {
      if (!v.is_number() || !(v.get<double>() >= lo && v.get<double>() <= hi))
        throw render::Error(fmt::format("{}: expected a number in [{}, {}], got {}", key, lo, hi, v.dump()));
      return v.get<double>();
    };
    auto count = [&]() {
      if (!v.is_number_integer() || v.get<int64_t>() < 1 || v.get<int64_t>() > (1 << 24))
        throw render::Error(
            fmt::format("{}: expected a whole number in [1, {}], got {}", key, 1 << 24, v.dump()));
      return int(v.get<int64_t>());
    };
    if (k == "target")
      o.target = number(1e-6, 10);
    else if (k == "quantile")
      o.quantile = number(0.5, 1);
    else if (k == "min_spp")
      o.min_spp = count();
    else if (k == "max_spp")
      o.max_spp = count();
    else
      throw render::Error(
          fmt::format("{}: unknown key; the keys are target, quantile, min_spp, max_spp", key));
  }
  if (o.min_spp > o.max_spp)
    throw render::Error(
        fmt::format("{}: min_spp {} is above max_spp {}; lower min_spp", origin, o.min_spp, o.max_spp));
  return o;
}

scene::Scene reference_scene(const scene::Scene& s) {
  scene::Scene r = s;
  // Guiding is unbiased and lowers the variance where light scatters towards the camera; the renderer uses
  // it only where the scene has a medium and a light. Its default settings, not the scene's: the key ignores
  // guiding, so every run that shares the reference must get the same one.
  r.guiding = guiding::GuidingParams{};
  r.guiding.enabled = true;
  r.denoise.surface.enabled = false;
  r.denoise.volume.enabled = false;
  r.render.outputs = {"exr", "png"};
  r.render.seed = kReferenceSeed;
  r.render.time_budget_s = 0;      // the reference counts its own samples
  r.render.estimator = "default";  // both estimators converge to the same image; the default sooner
  return r;
}

json reference_identity(const scene::Scene& s, const ReferenceOptions& o) {
  json j = scene::to_json(s);
  j.erase("guiding");
  j.erase("denoise");
  for (const char* k : {"spp", "time_budget_s", "seed", "volume_samples", "majorant_resolution",
                        "equiangular_probability", "rr_threshold", "sun_walk_probability", "sun_walk_g",
                        "walk_splits", "estimator", "outputs", "exposure", "tonemap", "frames"})
    j["render"].erase(k);
  // Files by content, so that the key is the same wherever the scene and its files are copied to. A
  // sequence's files are checked per frame instead (frame_inputs), so a longer range extends the reference.
  auto contents = [&](const char* list, size_t i, const char* field) {
    json& entry = j[list][i];
    if (!entry.contains(field) || !entry[field].is_string() || entry[field].get<std::string>().empty())
      return;
    const std::string pattern = entry[field].get<std::string>();
    entry[field] = scene::is_sequence(pattern) ? json{{"sequence", fs::path(pattern).filename().string()}}
                                               : json{{"content", file_hash(pattern)}};
  };
  for (size_t i = 0; i < s.media.size(); ++i) contents("media", i, "file");
  for (size_t i = 0; i < s.surfaces.size(); ++i) {
    contents("surfaces", i, "file");
    contents("surfaces", i, "albedo_texture");
  }
  return {{"scene", j}, {"options", o.to_json()}, {"version", 2}};  // 2: frames hold the denoised stand-ins
}

std::string reference_key(const scene::Scene& s, const ReferenceOptions& o) {
  return hash_key(reference_identity(s, o).dump());
}

std::string frame_inputs(const scene::Scene& s, int frame) {
  std::string all;
  for (const auto& m : s.media)
    if (scene::is_sequence(m.file)) all += file_hash(scene::frame_file(m.file, frame));
  return hash_key(all);
}

int next_check_spp(int spp, double error, const ReferenceOptions& o) {
  // e falls as 1/sqrt(n): n (e / target)^2 samples reach the target; 10% more for the estimate's noise,
  // at most 4x per round so that a noisy first estimate cannot overshoot far.
  double want = 1.1 * double(spp) * (error / o.target) * (error / o.target);
  if (!std::isfinite(want)) want = 4.0 * double(spp);  // an infinite or NaN error: the largest step
  const double capped = std::clamp(std::ceil(want), double(spp) + 1, 4.0 * double(spp));
  return int(std::min<double>(capped, o.max_spp));
}

std::string not_converged_note(const ReferenceFrame& f, const ReferenceOptions& o) {
  return fmt::format(
      "reference frame {} did not converge: error {:.3g} at quantile {} after {} spp ({:.1f} s), target {}; "
      "about {:.0f} spp would reach it: raise max_spp or the target",
      f.frame, f.error_quantile, o.quantile, f.spp, f.seconds, o.target,
      std::ceil(double(f.spp) * (f.error_quantile / o.target) * (f.error_quantile / o.target)));
}

std::string reference_png_path(const std::string& dir, int frame) {
  return (fs::path(dir) / fmt::format("frame_{:04d}.png", frame)).string();
}

std::string reference_frame_path(const std::string& dir, int frame) {
  return (fs::path(dir) / fmt::format("frame_{:04d}.exr", frame)).string();
}

json ReferenceFrame::to_json() const {
  return {{"frame", frame},
          {"spp", spp},
          {"error_quantile", error_quantile},
          {"error_max", error_max},
          {"converged", converged},
          {"seconds", seconds}};
}

std::vector<float> relative_standard_errors(const render::Image& img) {
  const size_t pixels = size_t(img.width) * img.height;
  std::vector<float> e(pixels, 0.f);
  const double n = std::max(img.samples, 1);
  for (size_t p = 0; p < pixels; ++p) {
    double worst = 0;
    for (uint32_t c = 0; c < 3; ++c) {
      const double mean = img.data[p * glsl::OUT_STRIDE + glsl::OUT_L + c];
      const double var = img.data[p * glsl::OUT_STRIDE + glsl::OUT_VAR + c];
      worst = std::max(worst, std::sqrt(var / n / relmse_denominator(mean)));
    }
    e[p] = std::isfinite(worst) ? float(worst) : INFINITY;
  }
  return e;
}

json make_reference(gpu::Context& ctx, const scene::Scene& s_in, int first, int last, const std::string& dir,
                    const ReferenceOptions& o, const ReferenceHooks& hooks,
                    std::unique_ptr<render::Renderer>& r) {
  using clock = std::chrono::steady_clock;
  const scene::Scene s = reference_scene(s_in);
  render::ensure_writable_dir(dir);
  FileLock lock((fs::path(dir) / ".lock").string());
  const std::string key = reference_key(s, o);
  const std::string info_path = (fs::path(dir) / "reference.json").string();
  json info = {{"key", key}, {"identity", reference_identity(s, o)}, {"frames", json::object()}};
  if (fs::exists(info_path)) {
    json old;
    try {
      std::ifstream f(info_path);
      old = json::parse(f);
    } catch (const std::exception&) {
      throw render::Error(
          fmt::format("{}: not a reference.json (bad JSON); delete it or choose another --out", info_path));
    }
    if (old.value("key", "") != key)
      throw render::Error(
          fmt::format("{} holds the reference of another scene or settings (key {}, this one is {}); choose "
                      "another --out",
                      dir, old.value("key", "?"), key));
    info["frames"] = old.value("frames", json::object());
  }
  bool fresh = true;
  for (int f = first; f <= last; ++f) {
    const std::string fkey = std::to_string(f);
    const std::string inputs = frame_inputs(s, f);
    if (info["frames"].contains(fkey) && info["frames"][fkey].value("inputs", "") == inputs &&
        fs::exists(reference_frame_path(dir, f))) {
      if (hooks.on_frame) {
        ReferenceFrame rf;
        rf.frame = f;
        rf.spp = info["frames"][fkey].value("spp", 0);
        rf.error_quantile = info["frames"][fkey].value("error_quantile", 0.0);
        rf.error_max = info["frames"][fkey].value("error_max", 0.0);
        rf.converged = info["frames"][fkey].value("converged", false);
        hooks.on_frame(rf, true);
      }
      continue;
    }
    auto t0 = clock::now();
    render::use_frame(ctx, r, s, f, fresh);
    fresh = false;
    ReferenceFrame rf;
    rf.frame = f;
    render::Image img;
    int next = std::min(o.min_spp, o.max_spp);
    for (;;) {
      r->add_samples(next - r->samples());
      img = r->resolve();
      std::vector<float> e = relative_standard_errors(img);
      const size_t k =
          std::min(e.size(), size_t(std::max(1.0, std::ceil(o.quantile * double(e.size()))))) - 1;
      std::nth_element(e.begin(), e.begin() + long(k), e.end());
      rf.error_quantile = e[k];
      rf.error_max = *std::max_element(e.begin(), e.end());
      rf.spp = r->samples();
      rf.converged = rf.error_quantile <= o.target;
      rf.seconds = std::chrono::duration<double>(clock::now() - t0).count();
      if (hooks.on_check) hooks.on_check(rf);
      if (rf.converged || rf.spp >= o.max_spp) break;
      next = next_check_spp(rf.spp, rf.error_quantile, o);
    }
    write_reference_frame(reference_frame_path(dir, f), img);
    render::write_png(reference_png_path(dir, f), img);
    info["frames"][fkey] = rf.to_json();
    info["frames"][fkey]["inputs"] = inputs;
    if (!rf.converged) info["frames"][fkey]["note"] = not_converged_note(rf, o);
    info["frames"][fkey]["features"] = r->stats()["features"];  // "guiding" among them where it applied
    render::write_json(info_path, info);  // after each frame: a killed run keeps the frames it finished
    if (hooks.on_frame) hooks.on_frame(rf, false);
  }
  return info;
}

}  // namespace haze::eval
