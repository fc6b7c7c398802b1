#include "bench/bench.hpp"

#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <map>
#include <set>
#include <sstream>

#include "bench/bench_util.hpp"
#include "bench/efficiency_bench.hpp"
#include "bench/gather_floor.hpp"
#include "bench/guiding_bench.hpp"
#include "bench/light_choice_bench.hpp"
#include "bench/shafts_bench.hpp"
#include "bench/velocity_bench.hpp"
#include "bench/view_bench.hpp"
#include "bench/volume_repr_bench.hpp"
#include "denoise/svgf.hpp"
#include "render/renderer.hpp"
#include "scene/scene.hpp"
#include "surfaces/embree_ref.hpp"
#include "surfaces/scene_geometry.hpp"

namespace haze::bench {

namespace {

// The demo's ingredients at bench size: a procedural cloud over bounded haze, lit by a low sun.
nlohmann::json bench_scene(int w, int h, int spp) {
  return nlohmann::json::parse(fmt::format(R"({{
    "camera": {{"position": [0, 1.5, 9], "target": [0, 2.5, 0], "fov_y": 50}},
    "media": [{{"procedural": {{"kind": "cloud", "voxel_size": 0.06, "center": [0, 4, 0], "size": [5, 5, 5],
                               "density": 4, "falloff": 0.6, "frequency": 1.2, "seed": 3}},
               "albedo": [0.95, 0.95, 0.95], "g": 0.6}}],
    "haze": {{"sigma_t": 0.08, "albedo": [0.9, 0.9, 0.9], "g": 0.5, "bounded": true,
             "bounds_min": [-30, -1, -30], "bounds_max": [30, 12, 30]}},
    "lights": {{"sun": {{"direction": [0.4, 0.5, -0.6], "irradiance": 6}},
               "environment": {{"color": [0.3, 0.4, 0.6], "intensity": 1}}}},
    "render": {{"width": {}, "height": {}, "spp": {}, "max_depth": 2}}
  }})",
                                           w, h, spp));
}

// The yardstick: a copy kernel over `floats` floats (vec4 granularity), recorded between the submissions of
// the pass it is compared with, so that both see the same state of a shared, drifting machine.
class CopyKernel {
 public:
  CopyKernel(gpu::Context& ctx, size_t floats)
      : count_(uint32_t((floats + 3) / 4)),
        src_(ctx, "bench copy source", "benchmark", uint64_t(count_) * 16, "RGBA32F"),
        dst_(ctx, "bench copy destination", "benchmark", uint64_t(count_) * 16, "RGBA32F"),
        kernel_(ctx, gpu::KernelDecl("bench/copy.comp")
                         .buffer("src", uint64_t(count_) * 16)
                         .buffer("dst", uint64_t(count_) * 16)
                         .push(4)) {
    src_.fill_zero();
    bindings_.set("src", src_).set("dst", dst_);
  }
  void record(VkCommandBuffer cmd) const { kernel_.dispatch_1d(cmd, bindings_, &count_, count_); }

 private:
  uint32_t count_;
  gpu::Buffer src_, dst_;
  gpu::Kernel kernel_;
  gpu::Bindings bindings_;
};

// GPU time of one submission of `record`.
double time_once(gpu::Context& ctx, gpu::Timer& timer, const Record& record) {
  ctx.submit_and_wait([&](VkCommandBuffer cmd) {
    timer.reset(cmd);
    timer.begin(cmd, "bench");
    record(cmd);
    timer.end(cmd);
  });
  return timer.read_ms().at(0).second;
}

// The kernels bench_svgf times beside the instance's passes, not part of its total.
const char* const kYardsticks[] = {"copy", "roofline", "gather_floor"};
bool is_yardstick(const std::string& pass) {
  return std::find(std::begin(kYardsticks), std::end(kYardsticks), pass) != std::end(kYardsticks);
}

// Median per-pass GPU times (ms) of the surface SVGF instance over `reps` frames of a synthetic input:
// a tilted plane with 1-spp-like noise and a slow pan, after two warm-up frames; "copy": the copy kernel,
// recorded after each frame's passes in the same submission, then "roofline" and "gather_floor".
std::map<std::string, double> bench_svgf(gpu::Context& ctx, uint32_t W, uint32_t H, const std::string& kernel,
                                         int reps, const CopyKernel& copy, const CopyKernel& roofline,
                                         const GatherFloor& gather) {
  const size_t pixels = size_t(W) * H;
  std::vector<float> colour(pixels * 3), g(pixels * glsl::G_STRIDE, 0.f);
  uint32_t rng = 1;
  for (size_t p = 0; p < pixels; ++p) {
    const float x = float(p % W) / W, y = float(p / W) / H;
    for (int c = 0; c < 3; ++c)
      colour[p * 3 + c] = (0.2f + 0.6f * x) * -std::log(glsl::rng_next(rng) + 1e-7f);
    float* q = &g[p * glsl::G_STRIDE];
    q[glsl::G_DEPTH] = q[glsl::G_PREV_DEPTH] = 2.f + y;
    q[glsl::G_DDEPTH + 1] = 1.f / H;
    glm::vec2 n = glsl::oct_encode(glm::normalize(glm::vec3(0, 0.3f, 1)));
    q[glsl::G_NORMAL] = n.x;
    q[glsl::G_NORMAL + 1] = n.y;
    q[glsl::G_ALBEDO] = q[glsl::G_ALBEDO + 1] = q[glsl::G_ALBEDO + 2] = 0.5f;
    q[glsl::G_INSTANCE] = 0.f;
    q[glsl::G_MOTION] = 0.5f;
  }
  gpu::Buffer in(ctx, "bench svgf colour", "benchmark", colour.size() * 4, "3 x f32");
  gpu::PixelLayers gb(ctx, "bench svgf g-buffer", "benchmark", pixels, render::kGBufferLayers);
  gpu::PixelLayers prev(ctx, "bench svgf previous g-buffer", "benchmark", pixels, render::kPrevGBufferLayers);
  in.upload(colour);
  gb.upload(g);
  prev.upload(g);
  denoise::SvgfParams params;
  params.kernel = kernel;
  denoise::Svgf svgf(ctx, "bench", params, W, H, true);
  gpu::Timer timer(ctx);
  std::map<std::string, std::vector<double>> ms;
  for (int i = 0; i < reps + 2; ++i) {
    ctx.submit_and_wait([&](VkCommandBuffer cmd) {
      timer.reset(cmd);
      svgf.run(cmd, &timer, {&in, 3, 0, &gb, &prev, &gb[glsl::G_MOTION / 4], 4, glsl::G_MOTION % 4});
      gpu::compute_barrier(cmd);
      timer.begin(cmd, "svgf.bench.copy");
      copy.record(cmd);
      timer.end(cmd);
      gpu::compute_barrier(cmd);
      timer.begin(cmd, "svgf.bench.roofline");
      roofline.record(cmd);
      timer.end(cmd);
      gpu::compute_barrier(cmd);
      timer.begin(cmd, "svgf.bench.gather_floor");
      gather.record(cmd);
      timer.end(cmd);
    });
    auto t = timer.read_ms();
    if (i < 2) continue;
    for (auto& [pass, v] : t) ms[pass.substr(std::string("svgf.bench.").size())].push_back(v);
  }
  std::map<std::string, double> out;
  double total = 0;
  for (auto& [pass, v] : ms)
    if (!is_yardstick(pass)) total += out[pass] = render::median(v);
  out["total"] = total;
  for (const char* y : kYardsticks) out[y] = render::median(ms.at(y));
  return out;
}

// The roofline of the bench's surface instance (adaptive mode, gather, surface geometry): the bytes per pixel
// it must read and write once per frame if every input were read once and every output written once, in the
// stored precision. Reads: noisy colour 3 f32, motion 2 f32, this frame's G-buffer fields the passes use (z,
// dz.xy, z_prev, octahedral normal 2, albedo 3: 9 f32), the previous frame's (z, normal: 3 f32), the history
// colour (RGBA16F), moments (m1, m2, n: 3 f32) and last TAA output (RGBA16F). Writes: the history colour,
// moments and TAA output. Temporaries between passes (percentiles, ping-pong buffers) are not counted.
constexpr size_t kSvgfRooflineRead = (3 + 2 + 9 + 3) * 4 + 8 + denoise::glsl::SVGF_MOMENTS_STRIDE * 4 + 8;
constexpr size_t kSvgfRooflineWritten = 8 + denoise::glsl::SVGF_MOMENTS_STRIDE * 4 + 8;

// BVH rays per second on the GPU and through Embree's CPU intersector (all threads): the same random rays
// over a slatted window, a sphere, a perforated panel and a floor.
struct BvhFigures {
  double gpu_rays_per_s = 0, embree_rays_per_s = 0;
  size_t triangles = 0;
};

BvhFigures bench_bvh(gpu::Context& ctx) {
  nlohmann::json j = {
      {"surfaces",
       {{{"mesh", {{"kind", "window"}, {"slats", 12}}}},
        {{"mesh", {{"kind", "sphere"}, {"radius", 0.5}, {"segments", 64}}},
         {"transform", {{"translate", {1, 0, 0}}}}},
        {{"mesh", {{"kind", "perforated_panel"}, {"holes_x", 8}, {"holes_y", 8}}},
         {"transform", {{"translate", {0, 0, -1}}}}},
        {{"mesh", {{"kind", "box"}, {"size", {3, 0.1, 3}}}}, {"transform", {{"translate", {0, -1, 0}}}}}}}};
  scene::Scene s = scene::from_json(j, "bench surfaces", "");
  surfaces::SceneGeometry geo = surfaces::build_geometry(s);
  const size_t n = 1 << 18;
  std::vector<glsl::GpuRay> rays(n);
  uint32_t state = glsl::rng_init(5u, 0u, 0u);
  for (auto& r : rays) {
    // One number at a time: C++ leaves the order of a call's arguments to the compiler.
    const float ox = glsl::rng_next(state), oy = glsl::rng_next(state), oz = glsl::rng_next(state);
    const float u1 = glsl::rng_next(state), u2 = glsl::rng_next(state);
    glm::vec3 o = glm::vec3(ox, oy, oz) * 4.f - 2.f;
    glm::vec3 d = glsl::sample_uniform_sphere(glm::vec2(u1, u2));
    r.origin_tmin = glm::vec4(o, 0);
    r.direction_tmax = glm::vec4(d, 1e30f);
  }
  auto dev = surfaces::upload(ctx, geo.bvh);
  gpu::Buffer ray_buf(ctx, "bench rays", "benchmark", n * sizeof(glsl::GpuRay), "GpuRay");
  ray_buf.upload(rays);
  gpu::Buffer hit_buf(ctx, "bench hits", "benchmark", n * sizeof(glsl::GpuRayHit), "GpuRayHit");
  gpu::Kernel trace(ctx, surfaces::trace_rays_decl(dev, n, false));
  gpu::Bindings b;
  dev.bind(b);
  b.set("rays", ray_buf).set("hits", hit_buf);
  uint32_t count = uint32_t(n);
  double gpu_ms =
      timed_median(ctx, 3, [&](VkCommandBuffer cmd) { trace.dispatch_1d(cmd, b, &count, count); });
  surfaces::EmbreeScene ref(geo.bvh.triangles);
  std::vector<double> cpu;
  for (int rep = 0; rep < 3; ++rep) {
    auto t0 = std::chrono::steady_clock::now();
    tbb::parallel_for(size_t(0), n, [&](size_t i) {
      ref.intersect(glm::vec3(rays[i].origin_tmin), glm::vec3(rays[i].direction_tmax), 0.f, 1e30f);
    });
    cpu.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  BvhFigures f;
  f.gpu_rays_per_s = n / (gpu_ms * 1e-3);
  f.embree_rays_per_s = n / (render::median(cpu) * 1e-3);
  f.triangles = geo.bvh.triangles.size();
  return f;
}

using nlohmann::json;

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, sep);) {
    item.erase(0, item.find_first_not_of(" \t"));
    item.erase(item.find_last_not_of(" \t") + 1);
    out.push_back(item);
  }
  return out;
}

std::pair<int, int> parse_size(const std::string& s, const std::string& what) {
  int w = 0, h = 0;
  char x = 0;
  if (std::sscanf(s.c_str(), "%d%c%d", &w, &x, &h) != 3 || (x != 'x' && x != 'X') || w < 1 || h < 1)
    throw std::runtime_error(fmt::format("{} {}: expected WIDTHxHEIGHT, e.g. 320x180", what, s));
  return {w, h};
}

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// Wall time (steady clock) from constructing a Renderer for the bench scene to its first resolve(), split
// into pipeline creation and the rest, against the median of steady-state frames of the same spp on that
// renderer.
// One first frame in a fresh context (no pipeline of this process): wall time from Renderer construction to
// the first resolve, the kernels' compile and creation time inside it, and steady frames after it.
json first_frame_case(const gpu::ContextOptions& co, const scene::Scene& s) {
  gpu::Context ctx(co);
  const int spp = s.render.spp;
  const auto t0 = std::chrono::steady_clock::now();
  render::Renderer r(ctx, s);
  const double construct = ms_since(t0);
  r.add_samples(spp);
  r.resolve();
  const double first = ms_since(t0);
  const double pipelines = r.pipeline_ms();
  const json shaders = r.stats()["shaders"];
  std::vector<double> steady;
  for (int i = 0; i < 3; ++i) {
    const auto t = std::chrono::steady_clock::now();
    r.add_samples(spp);
    r.resolve();
    steady.push_back(ms_since(t));
  }
  const double st = render::median(steady);
  return {{"first_frame_ms", first},
          {"construction_ms", construct},
          {"pipeline_creation_ms", pipelines},
          {"rest_ms", first - pipelines},
          {"steady_frame_ms", st},
          {"steady_frames", steady},
          {"first_over_steady", first / st},
          {"pipeline_share_of_first_frame", pipelines / first},
          {"shaders", shaders}};
}

// Time to first frame with cold caches (haze's SPIR-V cache and Mesa's disk cache both empty, in a
// temporary folder: glslang compiles every permutation, the driver every pipeline) and warm ones (the same
// folders as the cold run left them, in another fresh context). $MESA_SHADER_CACHE_DIR is read when a
// Vulkan instance starts, so each case's context sees the temporary folder.
json bench_first_frame(const gpu::ContextOptions& co, const scene::Scene& s) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / fmt::format("haze-bench-first-frame-{}", ::getpid());
  fs::remove_all(dir);
  const char* mesa = std::getenv("MESA_SHADER_CACHE_DIR");
  const std::string saved = mesa ? mesa : "";
  ::setenv("MESA_SHADER_CACHE_DIR", (dir / "mesa").c_str(), 1);
  gpu::ContextOptions c = co;
  c.shader_cache = (dir / "spirv").string();
  json cold, warm;
  try {
    cold = first_frame_case(c, s);
    warm = first_frame_case(c, s);
  } catch (...) {
    mesa ? ::setenv("MESA_SHADER_CACHE_DIR", saved.c_str(), 1) : ::unsetenv("MESA_SHADER_CACHE_DIR");
    fs::remove_all(dir);
    throw;
  }
  mesa ? ::setenv("MESA_SHADER_CACHE_DIR", saved.c_str(), 1) : ::unsetenv("MESA_SHADER_CACHE_DIR");
  std::error_code ec;
  fs::remove_all(dir, ec);
  return {{"spp", s.render.spp},
          {"cold", cold},
          {"warm", warm},
          {"cold_over_warm", cold["first_frame_ms"].get<double>() / warm["first_frame_ms"].get<double>()}};
}

// The tracker's passes against a copy of the accumulation buffer, throughput figures, and density lookups
// through the tracker's own sample_medium. Writes the keys at the top level of `j` (kept from earlier
// versions of the bench for scripts).
void bench_passes(gpu::Context& ctx, const scene::Scene& s, int w, int h, int spp, json& j) {
  render::Renderer r(ctx, s);
  const size_t pixels = size_t(w) * h;
  CopyKernel copy(ctx, pixels * glsl::ACC_STRIDE);
  gpu::Timer timer(ctx, 4);
  auto copy_once = [&] { return time_once(ctx, timer, [&](VkCommandBuffer cmd) { copy.record(cmd); }); };
  // Warm-ups (first-dispatch compiles), then each trace sample and resolve followed by one copy.
  r.add_samples(1);
  r.resolve();
  copy_once();
  std::vector<double> trace_ms, resolve_ms, copy_ms;
  for (int i = 0; i < std::max(spp, 3); ++i) {
    r.add_samples(1);
    trace_ms.push_back(r.pass_stats().at("trace").ms.back());
    copy_ms.push_back(copy_once());
  }
  for (int i = 0; i < 3; ++i) {
    r.resolve();
    resolve_ms.push_back(r.pass_stats().at("resolve").ms.back());
    copy_ms.push_back(copy_once());
  }
  const double t_trace = render::median(trace_ms), t_resolve = render::median(resolve_ms);
  const double t_copy = render::median(copy_ms);

  // Density lookups through the renderer's own media and scene block.
  struct {
    uint32_t count, lookups;
  } push{uint32_t(pixels), 16};
  gpu::Buffer out(ctx, "bench lookup result", "benchmark", pixels * 4, "f32");
  gpu::KernelDecl ld("bench/lookup.comp");
  ld.buffer("scene", sizeof(glsl::GpuScene));
  r.device_media().declare(ld);
  gpu::Kernel lookup(ctx, std::move(ld.buffer("result", pixels * 4).push(8)));
  gpu::Bindings lb;
  lb.set("scene", r.scene_buffer()).set("result", out);
  r.device_media().bind(lb);
  const auto lookup_and_copy =
      timed_medians(ctx, 3,
                    {[&](VkCommandBuffer cmd) { lookup.dispatch_1d(cmd, lb, &push, push.count); },
                     [&](VkCommandBuffer cmd) { copy.record(cmd); }});
  const double t_lookup = lookup_and_copy[0], t_lookup_copy = lookup_and_copy[1];
  double lookups = double(push.count) * push.lookups;
  j["copy_ms"] = t_copy;
  j["camera_rays_per_s"] = pixels / (t_trace * 1e-3);
  j["volume_samples_per_s"] = pixels * s.render.volume_samples / (t_trace * 1e-3);
  j["density_lookups_per_s"] = lookups / (t_lookup * 1e-3);
  j["passes"] = {
      {"trace", {{"median_ms", t_trace}, {"ratio_to_copy", t_trace / t_copy}}},
      {"resolve", {{"median_ms", t_resolve}, {"ratio_to_copy", t_resolve / t_copy}}},
      {"lookup (16 per pixel)",
       {{"median_ms", t_lookup}, {"copy_ms", t_lookup_copy}, {"ratio_to_copy", t_lookup / t_lookup_copy}}}};
  j["pipeline_creation_ms"] = r.pipeline_ms();
}

// The surface SVGF instance: per-pass and total times against a copy of one of its RGBA16F images.
json bench_svgf_sizes(gpu::Context& ctx, const std::string& sizes) {
  json dn = json::object();
  for (const std::string& sz : split(sizes, ',')) {
    auto [dw, dh] = parse_size(sz, "--denoise-sizes");
    CopyKernel copy(ctx, size_t(dw) * dh * 2);
    // The copy kernel reads and writes as many bytes as the instance's roofline moves in all.
    const size_t roofline_bytes = kSvgfRooflineRead + kSvgfRooflineWritten;
    CopyKernel roofline(ctx, size_t(dw) * dh * roofline_bytes / 8);
    GatherFloor gather(ctx, dw, dh);
    json entry = {
        {"image_mb", double(dw) * dh * 8 / 1e6},
        {"roofline_bytes_per_pixel", {{"read", kSvgfRooflineRead}, {"written", kSvgfRooflineWritten}}},
        {"copy_ms", json::object()},
        {"roofline_ms", json::object()},
        {"gather_floor_ms", json::object()}};
    for (const char* kernel : {"5x5", "subsampled"}) {
      json k = json::object();
      auto t = bench_svgf(ctx, dw, dh, kernel, 5, copy, roofline, gather);
      const double c = t.at("copy"), r = t.at("roofline");
      entry["copy_ms"][kernel] = c;
      entry["roofline_ms"][kernel] = r;
      entry["gather_floor_ms"][kernel] = t.at("gather_floor");
      for (auto& [pass, ms] : t)
        if (!is_yardstick(pass)) k[pass] = {{"median_ms", ms}, {"ratio_to_copy", ms / c}};
      k["total"]["ratio_to_roofline"] = t.at("total") / r;
      k["gather_floor"]["ratio_to_copy"] = t.at("gather_floor") / c;
      entry[kernel] = k;
    }
    dn[sz] = entry;
  }
  return dn;
}

// Every ratio of the run, each with its meaning: {key: {value, meaning[, min, max]}}, in print order.
json summarize(const json& j, const std::vector<std::string>& svgf_sizes) {
  json rows = json::array();
  auto add = [&](const std::string& key, double v, const std::string& meaning) {
    rows.push_back({{"key", key}, {"value", v}, {"meaning", meaning}});
  };
  if (j.contains("passes")) {
    add("trace/copy", j["passes"]["trace"]["ratio_to_copy"],
        "one trace dispatch (1 spp) / copy of the accumulation buffer");
    add("resolve/copy", j["passes"]["resolve"]["ratio_to_copy"],
        "resolve (means, denoisers, tonemap) / same copy");
    add("lookup/copy", j["passes"]["lookup (16 per pixel)"]["ratio_to_copy"],
        "16 tracker density lookups (sample_medium) per pixel / same copy");
  }
  if (j.contains("svgf_surface"))
    for (const std::string& sz : svgf_sizes)
      for (const char* kernel : {"5x5", "subsampled"}) {
        const json& e = j["svgf_surface"][sz];
        add(fmt::format("svgf.surface {} {}/copy", sz, kernel), e[kernel]["total"]["ratio_to_copy"],
            fmt::format("surface SVGF, all passes of a frame ({} a-trous) / copy of one RGBA16F image",
                        kernel));
        add(fmt::format("svgf.surface {} {}/roofline", sz, kernel), e[kernel]["total"]["ratio_to_roofline"],
            fmt::format(
                "same frame / the copy kernel moving the instance's roofline ({} B read, {} B written "
                "per pixel; roofline / copy {:.2f})",
                e["roofline_bytes_per_pixel"]["read"].get<size_t>(),
                e["roofline_bytes_per_pixel"]["written"].get<size_t>(),
                e["roofline_ms"][kernel].get<double>() / e["copy_ms"][kernel].get<double>()));
        if (std::string(kernel) == "subsampled")
          add(fmt::format("svgf.surface {} gather floor/copy", sz),
              e[kernel]["gather_floor"]["ratio_to_copy"],
              "the loads of one subsampled filter iteration without its math (7 taps of 16 B per pixel "
              "from a storage buffer, summed) / the same copy");
      }
  if (j.contains("view") && !j["view"].contains("skipped")) {
    const auto& r = j["view"]["wall_over_gpu"];
    add("viewer wall/GPU", r["mean"],
        fmt::format(
            "viewer frame wall time / GPU time of its passes, mean over seeds ({:.3f}..{:.3f}); goal <= 1.15",
            r["min"].get<double>(), r["max"].get<double>()));
  }
  if (j.contains("bvh"))
    add("BVH GPU/Embree", j["bvh"]["gpu_over_embree"],
        "BVH rays/s on the GPU / Embree rays/s on all CPU threads, same rays and triangles");
  if (j.contains("guiding")) {
    for (const auto& e : j["guiding"]["equal_time"]) {
      const auto& r = e["relmse_ratio_unguided_over_guided"];
      add(fmt::format("{} unguided/guided", e["scene"].get<std::string>()), e["relmse_ratio_of_means"],
          fmt::format("volume relMSE at equal GPU time, ratio of means over seeds (per seed {:.2f}..{:.2f}); "
                      ">1: guiding wins",
                      r["min"].get<double>(), r["max"].get<double>()));
      rows.back()["min"] = r["min"];
      rows.back()["max"] = r["max"];
    }
    const auto& v = j["guiding"]["volume_denoiser"];
    auto ratio = [&](const std::string& key, const json& r, const std::string& meaning) {
      add(key, r["ratio_of_means"],
          fmt::format("{} (ratio of means over seeds; per seed {:.2f}..{:.2f})", meaning,
                      r["min"].get<double>(), r["max"].get<double>()));
      rows.back()["min"] = r["min"];
      rows.back()["max"] = r["max"];
    };
    ratio(
        "motion surface/virtual pts", v["relmse_surface_motion_over_virtual_points"],
        "denoised volume relMSE on a panning shaft, surface / virtual-point motion; >1: virtual points win");
    ratio("motion backward/virtual pts", v["relmse_backward_over_virtual_points"],
          "the same, each pixel's own virtual point reprojected backward / projected forward; >1: forward "
          "wins");
    for (const auto& [key, label] : {std::pair<const char*, const char*>{"volume_denoiser", "panning shaft"},
                                     {"volume_occluder", "shaft before a moving occluder"}}) {
      ratio(fmt::format("geometry surface/vp {}", key == std::string("volume_denoiser") ? "pan" : "occluder"),
            j["guiding"][key]["relmse_surface_geometry_over_virtual_points"],
            fmt::format(
                "denoised volume relMSE, {}: surface G-buffer / virtual points as the volume's geometry",
                label));
    }
    const auto& c = v["instances"];
    add("svgf.volume/surface time", c["volume_over_surface_time"],
        "GPU time per frame of the two SVGF instances");
    add("svgf.volume/surface memory",
        c["volume"]["bytes"].get<double>() / c["surface"]["bytes"].get<double>(),
        "ledger bytes of the two SVGF instances");
  }
  if (j.contains("velocity")) {
    const auto& r = j["velocity"]["relmse_ratio_rigid_over_velocity_per_seed"];
    add("motion rigid/velocity", j["velocity"]["relmse_ratio_rigid_over_velocity"],
        fmt::format(
            "denoised volume relMSE on a moving smoke sequence, rigid-only / velocity motion, ratio of "
            "means over seeds (per seed {:.2f}..{:.2f}); >1: velocity wins",
            r["min"].get<double>(), r["max"].get<double>()));
  }
  if (j.contains("light_choice")) {
    const auto& r = j["light_choice"]["variance_ratio_uniform_over_power_per_seed"];
    add("light choice uniform/power", j["light_choice"]["variance_ratio_uniform_over_power"],
        fmt::format(
            "per-pixel variance of L with one bright and many dim point lights, uniform / power "
            "choice at equal samples, ratio of means over seeds (per seed {:.2f}..{:.2f}); >1: power wins",
            r["min"].get<double>(), r["max"].get<double>()));
    const auto& tc = j["light_choice"]["trace_time_ratio_power_over_uniform"];
    const auto& te = j["light_choice"]["trace_time_ratio_map_over_constant"];
    add("light choice power/uniform time", tc["median"],
        fmt::format("trace time per sample of the same scene, choice by power / uniform, median of adjacent "
                    "pairs ({:.2f}..{:.2f})",
                    tc["min"].get<double>(), tc["max"].get<double>()));
    add("env map/constant time", te["median"],
        fmt::format(
            "trace time per sample of a hazy room lit by a 512x256 map of one radiance / by the constant "
            "environment of that radiance (the map code's cost), median of adjacent pairs ({:.2f}..{:.2f})",
            te["min"].get<double>(), te["max"].get<double>()));
  }
  if (j.contains("efficiency"))
    for (const auto& c : j["efficiency"]["cases"]) {
      const std::string name = c["case"];
      const auto sides = c["sides"];
      add(name == "sheets" ? "guiding.sheets" : "efficiency." + name, c["efficiency_ratio"],
          fmt::format("1/(relMSE x time), {} / {}, ratio of means over seeds ({:.2f}..{:.2f}): {}",
                      sides[0].get<std::string>(), sides[1].get<std::string>(),
                      c["per_seed_ratio_min"].get<double>(), c["per_seed_ratio_max"].get<double>(),
                      c["what"].get<std::string>()));
      rows.back()["min"] = c["per_seed_ratio_min"];
      rows.back()["max"] = c["per_seed_ratio_max"];
    }
  if (j.contains("volume_repr"))
    for (const auto& g : j["volume_repr"]["grids"]) {
      const std::string id = g["name"];
      add(fmt::format("nanovdb/dense time {} rnd", id), g["lookups"]["time_ratio_nanovdb_over_dense"],
          fmt::format("{} random trilinear lookups, PNanoVDB / dense array; {}",
                      g["lookups"]["lookups_per_invocation"].get<int>(), g["what"].get<std::string>()));
      add(fmt::format("nanovdb/dense time {} march", id), g["march"]["time_ratio_nanovdb_over_dense"],
          fmt::format("{}-step march along random segments, PNanoVDB / dense array",
                      g["march"]["lookups_per_invocation"].get<int>()));
      add(fmt::format("nanovdb/dense memory {}", id), g["memory_ratio_nanovdb_over_dense"],
          fmt::format("NanoVDB grid bytes / dense array bytes ({:.0f}% of the bbox active)",
                      100 * g["active_fraction_of_bbox"].get<double>()));
    }
  if (j.contains("first_frame")) {
    const auto& f = j["first_frame"];
    add("first/steady frame cold", f["cold"]["first_over_steady"],
        "wall time Renderer construction -> first resolve / a steady frame, same spp; empty shader caches");
    add("first/steady frame warm", f["warm"]["first_over_steady"],
        "the same with haze's SPIR-V cache and Mesa's shader cache warm (a new process's second run)");
    add("first frame cold/warm", f["cold_over_warm"], "first frame with empty caches / with warm caches");
    add("kernel share of cold 1st frame", f["cold"]["pipeline_share_of_first_frame"],
        "compiling permutations and creating pipelines / the cold first frame");
  }
  if (j.contains("shafts")) {
    const auto& sh = j["shafts"];
    // A summary {mean, min, max} of the shaft sequence as a row with its range.
    auto add_range = [&](const std::string& name, const json& r, const std::string& meaning) {
      if (r.empty()) return;
      add(name, r["mean"],
          fmt::format("{} ({:+.3f}..{:+.3f})", meaning, r["min"].get<double>(), r["max"].get<double>()));
      rows.back()["min"] = r["min"];
      rows.back()["max"] = r["max"];
    };
    add_range("shafts contrast error f>=4", sh["contrast_error_from_frame_4"],
              "sheet contrast of the denoised volume term / the reference's - 1, frames 4..");
    add_range("shafts contrast error f>=4, accumulation only",
              sh["contrast_error_accumulation_only_from_frame_4"],
              "the same with the volume instance reduced to its temporal accumulation: what the reprojection "
              "alone keeps");
    for (const char* inst : {"surface", "volume"})
      add_range(fmt::format("shafts mean error {}", inst), sh[fmt::format("mean_error_{}", inst)],
                fmt::format("denoised {} mean luminance / the reference's - 1, over frames", inst));
    if (sh["temporal"]["volume"]["change_ratio"].is_number())
      add("shafts change ratio volume", sh["temporal"]["volume"]["change_ratio"],
          "frame-to-frame change of the denoised volume term / the reference's (1: no flicker, no lag)");
  }
  return rows;
}

// A command-line option holding a JSON object (empty: {}); `example` goes into the error.
json json_object_option(const std::string& text, const char* flag, const char* example) {
  if (text.empty()) return json::object();
  json j;
  try {
    j = json::parse(text);
  } catch (const std::exception& e) {
    throw std::runtime_error(
        fmt::format("{}: not JSON ({}); expected an object such as {}", flag, e.what(), example));
  }
  if (!j.is_object()) throw std::runtime_error(fmt::format("{}: expected a JSON object", flag));
  return j;
}

}  // namespace

const std::vector<std::string>& part_names() {
  static const std::vector<std::string> names = {"first_frame", "passes",   "bvh",          "svgf",
                                                 "guiding",     "velocity", "light_choice", "volume_repr",
                                                 "view",        "shafts",   "efficiency"};
  return names;
}

std::vector<std::string> parse_only(const std::string& only) {
  if (only.empty()) {
    // The efficiency comparison takes minutes and the shaft sequence's first run renders its references
    // (about 40 minutes on lavapipe): they run when named.
    std::vector<std::string> all = part_names();
    for (const char* named_only : {"efficiency", "shafts"})
      all.erase(std::find(all.begin(), all.end(), named_only));
    return all;
  }
  std::set<std::string> wanted;
  for (const std::string& name : split(only, ',')) {
    if (std::find(part_names().begin(), part_names().end(), name) == part_names().end()) {
      std::string valid;
      for (const auto& n : part_names()) valid += (valid.empty() ? "" : ", ") + n;
      throw std::runtime_error(fmt::format("--only: unknown part '{}'; valid parts: {}", name, valid));
    }
    wanted.insert(name);
  }
  std::vector<std::string> out;
  for (const auto& n : part_names())
    if (wanted.count(n)) out.push_back(n);
  return out;
}

int run(const Options& o, const gpu::ContextOptions& co) {
  // Every argument is checked before the device starts.
  const std::vector<std::string> parts = parse_only(o.only);
  auto wants = [&](const char* part) { return std::find(parts.begin(), parts.end(), part) != parts.end(); };
  auto [w, h] = parse_size(o.size, "--size");
  for (const std::string& sz : split(o.denoise_sizes, ',')) parse_size(sz, "--denoise-sizes");
  if (o.denoise_sizes.empty()) throw std::runtime_error("--denoise-sizes: expected WxH[,WxH...]");
  auto [gw, gh] = parse_size(o.guiding_size, "--guiding-size");
  auto [shw, shh] = parse_size(o.shafts_size, "--shafts-size");
  if (o.shafts_frames < 1)
    throw std::runtime_error(fmt::format("--shafts-frames {}: must be >= 1", o.shafts_frames));
  const json set_patch =
      json_object_option(o.shafts_set, "--shafts-set", R"('{"denoise": {"volume": {"iterations": 3}}}')");
  const json efficiency_set =
      json_object_option(o.efficiency_set, "--efficiency-set", R"('{"render": {"rr_threshold": 0.2}}')");
  if (o.shafts_reference_spp < 1)
    throw std::runtime_error(fmt::format("--shafts-reference-spp {}: must be >= 1", o.shafts_reference_spp));
  if (o.spp < 1) throw std::runtime_error(fmt::format("--spp {}: must be >= 1", o.spp));
  std::vector<std::string> efficiency_cases;
  if (!o.efficiency_cases.empty())
    for (const std::string& c : split(o.efficiency_cases, ',')) {
      const auto& names = efficiency_case_names();
      if (std::find(names.begin(), names.end(), c) == names.end())
        throw std::runtime_error(
            fmt::format("--efficiency-cases: unknown case '{}'; valid cases: {}", c, fmt::join(names, ", ")));
      efficiency_cases.push_back(c);
    }

  gpu::Context ctx(co);
  scene::Scene s = scene::from_json(bench_scene(w, h, o.spp), "bench scene", "");
  json j;
  j["device"] = ctx.describe();
  j["size"] = {w, h};
  j["spp"] = o.spp;
  j["parts"] = parts;
  // first_frame makes contexts of its own, so that no pipeline of this process is reused.
  if (wants("first_frame")) j["first_frame"] = bench_first_frame(co, s);
  if (wants("passes")) bench_passes(ctx, s, w, h, o.spp, j);
  if (wants("bvh")) {
    BvhFigures bvh = bench_bvh(ctx);
    j["bvh"] = {{"triangles", bvh.triangles},
                {"gpu_rays_per_s", bvh.gpu_rays_per_s},
                {"embree_rays_per_s", bvh.embree_rays_per_s},
                {"gpu_over_embree", bvh.gpu_rays_per_s / bvh.embree_rays_per_s}};
  }
  if (wants("svgf")) j["svgf_surface"] = bench_svgf_sizes(ctx, o.denoise_sizes);
  if (wants("guiding") && o.guiding_seeds > 0) {
    GuidingBenchOptions go;
    go.width = gw;
    go.height = gh;
    go.seeds = o.guiding_seeds;
    j["guiding"] = bench_guiding(ctx, go);
  }
  if (wants("velocity") && o.guiding_seeds > 0) {
    VelocityBenchOptions vo;
    vo.width = gw;
    vo.height = gh;
    vo.seeds = o.guiding_seeds;
    j["velocity"] = bench_velocity(ctx, vo);
  }
  if (wants("light_choice") && o.guiding_seeds > 0) {
    LightChoiceBenchOptions lo;
    lo.width = gw;
    lo.height = gh;
    lo.seeds = o.guiding_seeds;
    j["light_choice"] = bench_light_choice(ctx, lo);
  }
  if (wants("volume_repr")) {
    VolumeReprOptions vo;
    vo.invocations = uint32_t(w) * uint32_t(h);
    j["volume_repr"] = bench_volume_repr(ctx, vo);
  }
  if (wants("efficiency") && o.efficiency_seeds > 0) {
    EfficiencyOptions eo;
    eo.seeds = o.efficiency_seeds;
    eo.scale = o.efficiency_scale;
    eo.cases = efficiency_cases;
    eo.set_a = efficiency_set;
    j["efficiency"] = bench_efficiency(ctx, eo);
  }
  if (wants("view")) j["view"] = bench_view(co, s, ViewBenchOptions{});
  if (wants("shafts")) {
    ShaftsOptions so;
    so.width = shw;
    so.height = shh;
    so.frames = o.shafts_frames;
    so.reference_spp = o.shafts_reference_spp;
    so.reference_dir = o.reference_dir;
    so.images_dir = o.images_dir;
    so.set = set_patch;
    j["shafts"] = bench_shafts(ctx, so);
  }
  const std::vector<std::string> svgf_sizes = split(o.denoise_sizes, ',');
  const json rows = summarize(j, svgf_sizes);
  json summary = json::object();
  for (json r : rows) {
    const std::string key = r["key"];
    r.erase("key");
    summary[key] = r;
  }
  j["summary"] = summary;
  const uint64_t messages = ctx.validation_messages();
  j["validation_messages"] = messages;

  if (o.json) {
    fmt::print("{}\n", j.dump(2));
  } else {
    fmt::print("haze bench on {} ({}); parts: {}\n", ctx.device_name(), ctx.driver_info(),
               fmt::join(parts, ", "));
    fmt::print("summary: ratios measured in this run on this device (medians after a warm-up)\n");
    for (const auto& r : rows)
      fmt::print("  {:<34}{:>9.3g}  {}\n", r["key"].get<std::string>(), r["value"].get<double>(),
                 r["meaning"].get<std::string>());
    if (j.contains("first_frame")) {
      const auto& f = j["first_frame"];
      fmt::print("time to first frame at {}x{}, {} spp (wall clock, a fresh context each):\n", w, h,
                 f["spp"].get<int>());
      for (const char* c : {"cold", "warm"}) {
        const auto& x = f[c];
        fmt::print(
            "  {:<5} {:>7.0f} ms = kernels {:.0f} ms ({} compiled, {} from the cache, glslang {:.0f} ms) + "
            "rest "
            "{:.0f} ms; steady frame {:.0f} ms\n",
            c, x["first_frame_ms"].get<double>(), x["pipeline_creation_ms"].get<double>(),
            x["shaders"]["compiled"].get<int>(), x["shaders"]["cache_hits"].get<int>(),
            x["shaders"]["compile_ms"].get<double>(), x["rest_ms"].get<double>(),
            x["steady_frame_ms"].get<double>());
      }
    }
    if (j.contains("passes")) {
      size_t pixels = size_t(w) * h;
      fmt::print("tracker at {}x{}, {} spp (ratios: pass time / copy of the {:.3g} MB accumulation buffer)\n",
                 w, h, o.spp, pixels * glsl::ACC_STRIDE * 4 / 1e6);
      fmt::print("  {:<28}{:>14}\n", "camera rays / s",
                 fmt::format("{:.3g}", j["camera_rays_per_s"].get<double>()));
      fmt::print("  {:<28}{:>14}\n", "volume samples / s",
                 fmt::format("{:.3g}", j["volume_samples_per_s"].get<double>()));
      fmt::print("  {:<28}{:>14}\n", "density lookups / s",
                 fmt::format("{:.3g}", j["density_lookups_per_s"].get<double>()));
      fmt::print("  {:<28}{:>14}\n", "pass", "x copy");
      fmt::print("  {:<28}{:>14.1f}\n", "trace (1 spp)", j["passes"]["trace"]["ratio_to_copy"].get<double>());
      fmt::print("  {:<28}{:>14.1f}\n", "resolve", j["passes"]["resolve"]["ratio_to_copy"].get<double>());
      fmt::print("  {:<28}{:>14.1f}\n", "lookup (16 per pixel)",
                 j["passes"]["lookup (16 per pixel)"]["ratio_to_copy"].get<double>());
    }
    if (j.contains("bvh")) {
      const auto& b = j["bvh"];
      fmt::print("BVH ({} triangles): GPU {:.3g} rays/s, Embree CPU {:.3g} rays/s, GPU / Embree {:.2f}\n",
                 b["triangles"].get<size_t>(), b["gpu_rays_per_s"].get<double>(),
                 b["embree_rays_per_s"].get<double>(), b["gpu_over_embree"].get<double>());
    }
    if (j.contains("svgf_surface"))
      for (const std::string& sz : svgf_sizes) {
        const json& entry = j["svgf_surface"][sz];
        fmt::print("svgf.surface at {} (ratios: pass time / copy of one RGBA16F image, {:.3g} MB)\n", sz,
                   entry["image_mb"].get<double>());
        fmt::print("  {:<28}{:>14}{:>14}\n", "pass", "5x5", "subsampled");
        for (auto& [pass, v] : entry["5x5"].items())
          fmt::print("  {:<28}{:>14.1f}{:>14.1f}\n", pass, v["ratio_to_copy"].get<double>(),
                     entry["subsampled"].contains(pass)
                         ? entry["subsampled"][pass]["ratio_to_copy"].get<double>()
                         : 0.0);
        fmt::print("  {:<28}{:>14.1f}{:>14.1f}\n", "total / roofline",
                   entry["5x5"]["total"]["ratio_to_roofline"].get<double>(),
                   entry["subsampled"]["total"]["ratio_to_roofline"].get<double>());
      }
    if (j.contains("guiding")) print_guiding(j["guiding"]);
    if (j.contains("velocity")) print_velocity(j["velocity"]);
    if (j.contains("light_choice")) print_light_choice(j["light_choice"]);
    if (j.contains("volume_repr")) print_volume_repr(j["volume_repr"]);
    if (j.contains("efficiency")) print_efficiency(j["efficiency"]);
    if (j.contains("view")) print_view(j["view"]);
    if (j.contains("shafts")) print_shafts(j["shafts"]);
  }
  if (messages > 0) {
    fmt::print(stderr, "haze: {} Vulkan validation messages\n", messages);
    return 3;
  }
  return 0;
}

}  // namespace haze::bench
