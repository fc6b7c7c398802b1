#include "bench/bench.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cstdio>
#include <functional>

#include "render/renderer.hpp"
#include "scene/scene.hpp"

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

}  // namespace

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
  fmt::print("  {:<28}{:>14}\n", "pass", "x copy");
  fmt::print("  {:<28}{:>14.1f}\n", "trace (1 spp)", t_trace / t_copy);
  fmt::print("  {:<28}{:>14.1f}\n", "resolve", t_resolve / t_copy);
  fmt::print("  {:<28}{:>14.1f}\n", "lookup (16 per pixel)", t_lookup / t_copy);
  return 0;
}

}  // namespace haze::bench
