#include "bench/bench.hpp"

#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <functional>
#include <map>

#include "bench/guiding_bench.hpp"
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

// Median GPU time of `reps` submissions of `record`, after one warm-up (lavapipe compiles on the first
// dispatch).
double timed_median(gpu::Context& ctx, int reps, const std::function<void(VkCommandBuffer)>& record) {
  gpu::Timer timer(ctx, 4);
  std::vector<double> ms;
  for (int i = 0; i < reps + 1; ++i) {
    ctx.submit_and_wait([&](VkCommandBuffer cmd) {
      timer.reset(cmd);
      timer.begin(cmd, "bench");
      record(cmd);
      timer.end(cmd);
    });
    double t = timer.read_ms().at(0).second;
    if (i > 0) ms.push_back(t);
  }
  return render::median(ms);
}

// Median time of `reps` copies of `floats` floats (vec4 granularity).
double copy_ms(gpu::Context& ctx, size_t floats, int reps) {
  size_t vec4s = (floats + 3) / 4;
  gpu::Buffer src(ctx, "bench copy source", "benchmark", vec4s * 16, "RGBA32F");
  gpu::Buffer dst(ctx, "bench copy destination", "benchmark", vec4s * 16, "RGBA32F");
  src.fill_zero();
  gpu::ComputePipeline copy(ctx, render::spv_dir() + "/bench/copy.comp.0.spv", 2, 4);
  uint32_t count = uint32_t(vec4s);
  return timed_median(ctx, reps, [&](VkCommandBuffer cmd) {
    copy.dispatch(cmd, {&src, &dst}, &count, (count + 63) / 64);
  });
}

// Median per-pass GPU times (ms) of the surface SVGF instance over `reps` frames of a synthetic input:
// a tilted plane with 1-spp-like noise and a slow pan, after two warm-up frames.
std::map<std::string, double> bench_svgf(gpu::Context& ctx, uint32_t W, uint32_t H, const std::string& kernel,
                                         int reps) {
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
  gpu::Buffer gb(ctx, "bench svgf g-buffer", "benchmark", g.size() * 4, "G_* layout");
  in.upload(colour);
  gb.upload(g);
  denoise::SvgfParams params;
  params.kernel = kernel;
  denoise::Svgf svgf(ctx, "bench", params, W, H, true, render::spv_dir());
  gpu::Timer timer(ctx);
  std::map<std::string, std::vector<double>> ms;
  for (int i = 0; i < reps + 2; ++i) {
    ctx.submit_and_wait([&](VkCommandBuffer cmd) {
      timer.reset(cmd);
      svgf.run(cmd, &timer, {&in, 3, 0, &gb, &gb, &gb, glsl::G_STRIDE, glsl::G_MOTION});
    });
    auto t = timer.read_ms();
    if (i < 2) continue;
    for (auto& [pass, v] : t) ms[pass.substr(std::string("svgf.bench.").size())].push_back(v);
  }
  std::map<std::string, double> out;
  double total = 0;
  for (auto& [pass, v] : ms) total += out[pass] = render::median(v);
  out["total"] = total;
  return out;
}

}  // namespace

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
    glm::vec3 o = glm::vec3(glsl::rng_next(state), glsl::rng_next(state), glsl::rng_next(state)) * 4.f - 2.f;
    glm::vec3 d = glsl::sample_uniform_sphere(glm::vec2(glsl::rng_next(state), glsl::rng_next(state)));
    r.origin_tmin = glm::vec4(o, 0);
    r.direction_tmax = glm::vec4(d, 1e30f);
  }
  auto dev = surfaces::upload(ctx, geo.bvh);
  gpu::Buffer ray_buf(ctx, "bench rays", "benchmark", n * sizeof(glsl::GpuRay), "GpuRay");
  ray_buf.upload(rays);
  gpu::Buffer hit_buf(ctx, "bench hits", "benchmark", n * sizeof(glsl::GpuRayHit), "GpuRayHit");
  gpu::ComputePipeline trace(ctx, gpu::variant_spv(render::spv_dir(), "surfaces/trace_rays.comp", 0), 4, 4);
  uint32_t count = uint32_t(n);
  double gpu_ms = timed_median(ctx, 3, [&](VkCommandBuffer cmd) {
    trace.dispatch(cmd, {&dev.nodes, &dev.triangles, &ray_buf, &hit_buf}, &count, (count + 63) / 64);
  });
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

int run(const Options& o, const gpu::ContextOptions& co) {
  int w = 0, h = 0;
  if (std::sscanf(o.size.c_str(), "%dx%d", &w, &h) != 2 || w < 1 || h < 1)
    throw std::runtime_error(fmt::format("--size {}: expected WIDTHxHEIGHT", o.size));
  gpu::Context ctx(co);
  scene::Scene s = scene::from_json(bench_scene(w, h, o.spp), "bench scene", "");
  render::Renderer r(ctx, s);
  r.add_samples(1);  // warm-up: first-dispatch compile
  size_t warm = r.pass_stats().at("trace").ms.size();
  r.add_samples(o.spp);
  std::vector<double> trace_ms(r.pass_stats().at("trace").ms.begin() + warm,
                               r.pass_stats().at("trace").ms.end());
  r.resolve();
  r.resolve();
  const auto& res = r.pass_stats().at("resolve").ms;
  double t_trace = render::median(trace_ms), t_resolve = res.back();
  size_t pixels = size_t(w) * h;
  double t_copy = copy_ms(ctx, pixels * glsl::ACC_STRIDE, std::max(o.spp, 3));

  // Density lookups per second through the tracker's own sample_medium.
  const auto& dm = r.media();
  glsl::GpuScene gs = volume::build_gpu_scene(s, dm, 0, 0);
  gpu::Buffer scene_buf(ctx, "bench scene", "benchmark", sizeof(gs), "GpuScene");
  scene_buf.upload(&gs, sizeof(gs));
  gpu::Buffer nano(ctx, "bench nanovdb", "benchmark", dm.nanovdb.size() * 4, "NanoVDB");
  nano.upload(dm.nanovdb);
  gpu::Buffer media(ctx, "bench media", "benchmark", dm.media.size() * sizeof(glsl::GpuMedium), "GpuMedium");
  media.upload(dm.media);
  gpu::Buffer maj(ctx, "bench majorant", "benchmark", dm.majorant.sigma_max.size() * 4, "f32");
  maj.upload(dm.majorant.sigma_max);
  struct {
    uint32_t count, lookups;
  } push{uint32_t(pixels), 16};
  gpu::Buffer out(ctx, "bench lookup result", "benchmark", pixels * 4, "f32");
  gpu::ComputePipeline lookup(ctx, render::spv_dir() + "/bench/lookup.comp.0.spv", 5, 8);
  double t_lookup = timed_median(ctx, 3, [&](VkCommandBuffer cmd) {
    lookup.dispatch(cmd, {&scene_buf, &nano, &media, &maj, &out}, &push, (push.count + 63) / 64);
  });
  double lookups = double(push.count) * push.lookups;

  nlohmann::json j;
  j["device"] = ctx.describe();
  j["size"] = {w, h};
  j["spp"] = o.spp;
  j["copy_ms"] = t_copy;
  j["camera_rays_per_s"] = pixels / (t_trace * 1e-3);
  j["volume_samples_per_s"] = pixels * s.render.volume_samples / (t_trace * 1e-3);
  j["density_lookups_per_s"] = lookups / (t_lookup * 1e-3);
  j["passes"] = {{"trace", {{"median_ms", t_trace}, {"ratio_to_copy", t_trace / t_copy}}},
                 {"resolve", {{"ms", t_resolve}, {"ratio_to_copy", t_resolve / t_copy}}},
                 {"lookup (16 per pixel)", {{"median_ms", t_lookup}, {"ratio_to_copy", t_lookup / t_copy}}}};
  j["pipeline_creation_ms"] = r.pipeline_ms();
  BvhFigures bvh = bench_bvh(ctx);
  j["bvh"] = {{"triangles", bvh.triangles},
              {"gpu_rays_per_s", bvh.gpu_rays_per_s},
              {"embree_rays_per_s", bvh.embree_rays_per_s},
              {"gpu_over_embree", bvh.gpu_rays_per_s / bvh.embree_rays_per_s}};
  // The surface SVGF instance: per-pass and total times against a copy of one of its RGBA16F images.
  nlohmann::json dn = nlohmann::json::object();
  for (size_t at = 0; at < o.denoise_sizes.size();) {
    size_t comma = o.denoise_sizes.find(',', at);
    std::string sz = o.denoise_sizes.substr(at, comma == std::string::npos ? std::string::npos : comma - at);
    at = comma == std::string::npos ? o.denoise_sizes.size() : comma + 1;
    int dw = 0, dh = 0;
    if (std::sscanf(sz.c_str(), "%dx%d", &dw, &dh) != 2 || dw < 1 || dh < 1)
      throw std::runtime_error(fmt::format("--denoise-sizes {}: expected WxH[,WxH...]", o.denoise_sizes));
    double copy = copy_ms(ctx, size_t(dw) * dh * 2, 3);
    nlohmann::json entry = {{"copy_ms", copy}, {"image_mb", double(dw) * dh * 8 / 1e6}};
    for (const char* kernel : {"5x5", "subsampled"}) {
      nlohmann::json k = nlohmann::json::object();
      for (auto& [pass, t] : bench_svgf(ctx, dw, dh, kernel, 3))
        k[pass] = {{"median_ms", t}, {"ratio_to_copy", t / copy}};
      entry[kernel] = k;
    }
    dn[sz] = entry;
  }
  j["svgf_surface"] = dn;
  if (o.guiding_seeds > 0) {
    GuidingBenchOptions go;
    if (std::sscanf(o.guiding_size.c_str(), "%dx%d", &go.width, &go.height) != 2 || go.width < 1 ||
        go.height < 1)
      throw std::runtime_error(fmt::format("--guiding-size {}: expected WIDTHxHEIGHT", o.guiding_size));
    go.seeds = o.guiding_seeds;
    j["guiding"] = bench_guiding(ctx, go);
  }
  if (o.json) {
    fmt::print("{}\n", j.dump(2));
    return 0;
  }
  fmt::print(
      "haze bench on {} at {}x{}, {} spp (ratios: pass time / copy of the {} MB accumulation buffer)\n",
      ctx.device_name(), w, h, o.spp, pixels * glsl::ACC_STRIDE * 4 / 1e6);
  fmt::print("  {:<28}{:>14}\n", "camera rays / s",
             fmt::format("{:.3g}", j["camera_rays_per_s"].get<double>()));
  fmt::print("  {:<28}{:>14}\n", "volume samples / s",
             fmt::format("{:.3g}", j["volume_samples_per_s"].get<double>()));
  fmt::print("  {:<28}{:>14}\n", "density lookups / s",
             fmt::format("{:.3g}", j["density_lookups_per_s"].get<double>()));
  fmt::print("  {:<28}{:>14}\n", fmt::format("BVH rays / s ({} tris)", bvh.triangles),
             fmt::format("{:.3g}", bvh.gpu_rays_per_s));
  fmt::print("  {:<28}{:>14}\n", "Embree CPU rays / s", fmt::format("{:.3g}", bvh.embree_rays_per_s));
  fmt::print("  {:<28}{:>14.2f}\n", "BVH GPU / Embree", bvh.gpu_rays_per_s / bvh.embree_rays_per_s);
  fmt::print("  {:<28}{:>14}\n", "pass", "x copy");
  fmt::print("  {:<28}{:>14.1f}\n", "trace (1 spp)", t_trace / t_copy);
  fmt::print("  {:<28}{:>14.1f}\n", "resolve", t_resolve / t_copy);
  fmt::print("  {:<28}{:>14.1f}\n", "lookup (16 per pixel)", t_lookup / t_copy);
  for (auto& [sz, entry] : dn.items()) {
    fmt::print("svgf.surface at {} (ratios: pass time / copy of one RGBA16F image, {:.3g} MB)\n", sz,
               entry["image_mb"].get<double>());
    fmt::print("  {:<28}{:>14}{:>14}\n", "pass", "5x5", "subsampled");
    for (auto& [pass, v] : entry["5x5"].items())
      fmt::print("  {:<28}{:>14.1f}{:>14.1f}\n", pass, v["ratio_to_copy"].get<double>(),
                 entry["subsampled"].contains(pass) ? entry["subsampled"][pass]["ratio_to_copy"].get<double>()
                                                    : 0.0);
  }
  if (j.contains("guiding")) print_guiding(j["guiding"]);
  return 0;
}

}  // namespace haze::bench
