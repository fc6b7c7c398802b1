#include "bench/guiding_bench.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numeric>

#include "bench/bench_util.hpp"
#include "eval/metrics.hpp"
#include "render/renderer.hpp"
#include "scene/scene.hpp"

namespace haze::bench {

namespace {

using nlohmann::json;

// A beam of known place: the sun straight above shines through a 1 x 1 opening (x in [-0.5, 0.5], z in
// [5.5, 6.5]) in a ceiling of four slabs at y = 3. The camera looks along +z at it. `vdb`: the medium is a
// procedural cloud (heterogeneous, ratio tracking) instead of haze.
json shaft_scene(int w, int h, bool vdb, bool guiding, uint32_t seed) {
  auto slab = [](double cx, double cz, double sx, double sz) {
    return json{{"mesh", {{"kind", "box"}, {"size", {sx, 0.1, sz}}}},
                {"transform", {{"translate", {cx, 3.05, cz}}}}};
  };
  json j = {{"camera", {{"position", {0, 1, 0}}, {"target", {0, 1.2, 1}}, {"fov_y", 50}}},
            {"surfaces",
             {slab(-10.25, 5, 19.5, 30), slab(10.25, 5, 19.5, 30), slab(0, -2.25, 1, 15.5),
              slab(0, 13.25, 1, 13.5)}},
            {"lights", {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", 5}, {"angular_diameter", 0}}}}},
            {"render", {{"width", w}, {"height", h}, {"max_depth", 1}, {"seed", seed}}},
            {"denoise", {{"surface", {{"enabled", false}}}, {"volume", {{"enabled", false}}}}}};
  if (vdb)
    j["media"] = {{{"procedural",
                    {{"kind", "cloud"},
                     {"voxel_size", 0.1},
                     {"center", {0, 1, 6}},
                     {"size", {7, 7, 7}},
                     {"density", 0.4},
                     {"falloff", 0.5},
                     {"seed", 4}}},
                   {"albedo", {0.9, 0.9, 0.9}}}};
  else
    j["haze"] = {{"sigma_t", 0.1},
                 {"albedo", {0.9, 0.9, 0.9}},
                 {"bounded", true},
                 {"bounds_min", {-20, -1, 0}},
                 {"bounds_max", {20, 3, 12}}};
  if (guiding) j["guiding"] = {{"enabled", true}, {"probability", 0.5}, {"spacing", 8}};
  return j;
}

// Median GPU time of one trace dispatch, after a warm-up sample (lavapipe compiles on the first dispatch).
double trace_ms(gpu::Context& ctx, const scene::Scene& s, int samples) {
  render::Renderer r(ctx, s);
  r.add_samples(1);
  const size_t warm = r.pass_stats().at("trace").ms.size();
  r.add_samples(samples);
  const auto& ms = r.pass_stats().at("trace").ms;
  return render::median(std::vector<double>(ms.begin() + long(warm), ms.end()));
}

scene::Scene make(const json& j) {
  return scene::from_json(j, "guiding bench scene", "");
}

// Guided against unguided volume relMSE at equal GPU time, over seeds.
json equal_time(gpu::Context& ctx, const GuidingBenchOptions& o, bool vdb) {
  const int w = o.width, h = o.height;
  // Per-sample cost of each estimator, measured once: the guided one gets spp * (t_u / t_g) samples.
  const double t_u = trace_ms(ctx, make(shaft_scene(w, h, vdb, false, 1)), 6);
  const double t_g = trace_ms(ctx, make(shaft_scene(w, h, vdb, true, 1)), 6);
  const int spp_g = std::max(1, int(std::lround(o.spp * t_u / t_g)));
  scene::Scene ref_scene = make(shaft_scene(w, h, vdb, false, 7777));
  render::Renderer ref(ctx, ref_scene);
  ref.add_samples(o.spp * o.reference_factor);
  const render::Image ref_img = ref.resolve();
  std::vector<double> ratios, err_u, err_g;
  for (int seed = 1; seed <= o.seeds; ++seed) {
    render::Renderer u(ctx, make(shaft_scene(w, h, vdb, false, uint32_t(seed))));
    u.add_samples(o.spp);
    render::Renderer g(ctx, make(shaft_scene(w, h, vdb, true, uint32_t(seed))));
    g.add_samples(spp_g);
    err_u.push_back(eval::relmse(volume_of(u.resolve()), volume_of(ref_img)));
    err_g.push_back(eval::relmse(volume_of(g.resolve()), volume_of(ref_img)));
    ratios.push_back(err_u.back() / err_g.back());
  }
  return {{"scene", vdb ? "vdb shaft" : "haze shaft"},
          {"size", {w, h}},
          {"unguided_spp", o.spp},
          {"guided_spp", spp_g},
          {"guided_over_unguided_time_per_sample", t_g / t_u},
          {"reference_spp", o.spp * o.reference_factor},
          {"relmse_unguided", summary(err_u)},
          {"relmse_guided", summary(err_g)},
          {"relmse_ratio_unguided_over_guided", summary(ratios)}};
}

// The volume instance on a camera panning past the shaft, reprojected with the virtual points' motion or
// with the surface motion, against a reference sequence; and its time and memory next to the surface
// instance's.
json temporal(gpu::Context& ctx, const GuidingBenchOptions& o) {
  const int w = o.width, h = o.height;
  auto frame_scene = [&](int f, bool denoise, const std::string& motion, uint32_t seed) {
    json j = shaft_scene(w, h, false, true, seed);
    double x = -1.5 + 3.0 * f / std::max(1, o.frames - 1);
    j["camera"]["position"] = {x, 1, 0};
    j["camera"]["target"] = {x, 1.2, 1};
    j["denoise"] = {
        {"surface", {{"enabled", denoise}}}, {"volume", {{"enabled", denoise}}}, {"volume_motion", motion}};
    if (!denoise) j["guiding"]["enabled"] = false;
    return make(j);
  };
  std::vector<render::Image> refs;
  {
    std::unique_ptr<render::Renderer> r;
    for (int f = 0; f < o.frames; ++f) {
      scene::Scene s = frame_scene(f, false, "surface", 9000 + uint32_t(f));
      if (!r)
        r = std::make_unique<render::Renderer>(ctx, s);
      else
        r->set_scene(s, uint32_t(f));
      r->add_samples(o.spp * o.reference_factor);
      refs.push_back(r->resolve());
    }
  }
  json out = json::object();
  std::map<std::string, double> mean_err;
  for (const std::string motion : {"virtual_points", "surface"}) {
    std::unique_ptr<render::Renderer> r;
    std::vector<double> errors;
    scene::Scene prev;
    for (int f = 0; f < o.frames; ++f) {
      scene::Scene s = frame_scene(f, true, motion, uint32_t(f + 1));
      if (!r)
        r = std::make_unique<render::Renderer>(ctx, s);
      else
        r->set_scene(s, uint32_t(f), &prev);
      prev = s;
      r->add_samples(o.sequence_spp);
      render::Image img = r->resolve();
      // The first frames have no history yet; the error that motion vectors change is the steady one.
      if (f >= 2) errors.push_back(eval::relmse(denoised_volume_of(img), volume_of(refs[size_t(f)])));
    }
    mean_err[motion] = std::accumulate(errors.begin(), errors.end(), 0.0) / double(errors.size());
    out[motion] = {{"relmse_per_frame", errors}, {"relmse_mean", mean_err[motion]}};
    if (motion == "virtual_points") {
      // Per frame medians of each instance's passes, and its memory by ledger category.
      json cost = json::object();
      for (const std::string inst : {"surface", "volume"}) {
        double ms = 0;
        for (const auto& [pass, st] : r->pass_stats())
          if (pass.rfind("svgf." + inst + ".", 0) == 0) ms += render::median(st.ms);
        uint64_t bytes = 0;
        for (const auto& [cat, b] : ctx.ledger().per_category())
          if (cat.rfind("svgf." + inst + " ", 0) == 0) bytes += b;
        cost[inst] = {{"ms_per_frame", ms}, {"bytes", bytes}};
      }
      cost["volume_over_surface_time"] =
          cost["volume"]["ms_per_frame"].get<double>() / cost["surface"]["ms_per_frame"].get<double>();
      double vm = 0;
      for (const auto& [pass, st] : r->pass_stats())
        if (pass == "volume_motion" || pass == "guide_reproject") vm += render::median(st.ms);
      cost["volume_motion_and_guide_reuse_ms_per_frame"] = vm;
      out["instances"] = cost;
    }
  }
  out["frames"] = o.frames;
  out["sequence_spp"] = o.sequence_spp;
  out["reference_spp"] = o.spp * o.reference_factor;
  out["relmse_ratio_surface_motion_over_virtual_points"] = mean_err["surface"] / mean_err["virtual_points"];
  return out;
}

}  // namespace

json bench_guiding(gpu::Context& ctx, const GuidingBenchOptions& o) {
  return {{"equal_time", {equal_time(ctx, o, false), equal_time(ctx, o, true)}},
          {"volume_denoiser", temporal(ctx, o)}};
}

void print_guiding(const json& j) {
  fmt::print("distance guiding at equal GPU time (volume relMSE, unguided / guided, over seeds)\n");
  fmt::print("  {:<14}{:>10}{:>10}{:>12}{:>8}{:>8}{:>8}\n", "scene", "spp u", "spp g", "t_g / t_u", "mean",
             "min", "max");
  for (const auto& e : j["equal_time"]) {
    const auto& r = e["relmse_ratio_unguided_over_guided"];
    fmt::print("  {:<14}{:>10}{:>10}{:>12.2f}{:>8.2f}{:>8.2f}{:>8.2f}\n", e["scene"].get<std::string>(),
               e["unguided_spp"].get<int>(), e["guided_spp"].get<int>(),
               e["guided_over_unguided_time_per_sample"].get<double>(), r["mean"].get<double>(),
               r["min"].get<double>(), r["max"].get<double>());
  }
  const auto& v = j["volume_denoiser"];
  fmt::print(
      "volume instance on a panning shaft ({} frames, {} spp): relMSE surface motion / virtual points "
      "{:.2f}\n",
      v["frames"].get<int>(), v["sequence_spp"].get<int>(),
      v["relmse_ratio_surface_motion_over_virtual_points"].get<double>());
  const auto& c = v["instances"];
  fmt::print("  svgf.volume / svgf.surface time {:.2f}; memory {:.2f} MB / {:.2f} MB\n",
             c["volume_over_surface_time"].get<double>(), c["volume"]["bytes"].get<double>() / 1e6,
             c["surface"]["bytes"].get<double>() / 1e6);
}

}  // namespace haze::bench
