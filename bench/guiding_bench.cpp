#include "bench/guiding_bench.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
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
  // The guide at its defaults (the histogram, a vertex every 10 pixels), P 0.5 where it is not chosen.
  if (guiding) j["guiding"] = {{"enabled", true}, {"probability", 0.5}};
  return j;
}

// Median GPU times of one trace dispatch of two scenes, their samples interleaved one by one after a warm-up
// sample each (lavapipe compiles on the first dispatch), so that the machine's drift touches both alike.
std::pair<double, double> trace_ms(gpu::Context& ctx, const scene::Scene& a, const scene::Scene& b,
                                   int samples) {
  render::Renderer ra(ctx, a), rb(ctx, b);
  ra.add_samples(1);
  rb.add_samples(1);
  for (int i = 0; i < samples; ++i) {
    ra.add_samples(1);
    rb.add_samples(1);
  }
  auto median_after_warmup = [](const render::Renderer& r) {
    const auto& ms = r.pass_stats().at("trace").ms;
    return render::median(std::vector<double>(ms.begin() + 1, ms.end()));
  };
  return {median_after_warmup(ra), median_after_warmup(rb)};
}

scene::Scene make(const json& j) {
  return scene::from_json(j, "guiding bench scene", "");
}

// Guided against unguided volume relMSE at equal GPU time, over seeds.
json equal_time(gpu::Context& ctx, const GuidingBenchOptions& o, bool vdb) {
  const int w = o.width, h = o.height;
  // Per-sample cost of each estimator, measured once: the guided one gets spp * (t_u / t_g) samples.
  const auto [t_u, t_g] =
      trace_ms(ctx, make(shaft_scene(w, h, vdb, false, 1)), make(shaft_scene(w, h, vdb, true, 1)), 16);
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
          {"relmse_ratio_unguided_over_guided", summary(ratios)},
          // The figure: a ratio of means over seeds (the mean of per-seed ratios is biased upward).
          {"relmse_ratio_of_means", std::accumulate(err_u.begin(), err_u.end(), 0.0) /
                                        std::accumulate(err_g.begin(), err_g.end(), 0.0)}};
}

// A shaft in front of a far wall (z = 12) with a box moving behind the shaft, between it and the wall, seen
// by a camera that does not move: the surface G-buffer changes where the air in front of it does not.
json occluder_scene(int w, int h, int frame, int frames, uint32_t seed) {
  json j = shaft_scene(w, h, false, true, seed);
  j["camera"] = {{"position", {0, 1.2, 0}}, {"target", {0, 1.4, 1}}, {"fov_y", 50}};
  const double x = -2.0 + 4.0 * frame / std::max(1, frames - 1);
  j["surfaces"].push_back({{"mesh", {{"kind", "box"}, {"size", {8, 6, 0.2}}}},
                           {"transform", {{"translate", {0, 1, 12}}}},
                           {"albedo", {0.6, 0.6, 0.6}}});
  j["surfaces"].push_back({{"mesh", {{"kind", "box"}, {"size", {0.8, 2.0, 0.3}}}},
                           {"transform", {{"translate", {x, 0.8, 8.5}}}},
                           {"albedo", {0.8, 0.3, 0.2}}});
  return j;
}

// The panning camera of the motion figure.
json panning_scene(int w, int h, int frame, int frames, uint32_t seed) {
  json j = shaft_scene(w, h, false, true, seed);
  const double x = -1.5 + 3.0 * frame / std::max(1, frames - 1);
  j["camera"]["position"] = {x, 1, 0};
  j["camera"]["target"] = {x, 1.2, 1};
  return j;
}

// The volume instance on a sequence against a reference sequence, per seed: mean relMSE of the denoised
// volume term over frames 2.. (the first have no history yet) and the temporal stability of the sequence.
struct SequenceFigures {
  std::vector<double> relmse, change_relmse;
};

json summary_ratio(const std::vector<double>& num, const std::vector<double>& den) {
  // The ratio of the means over seeds, and the spread of the per-seed ratios.
  std::vector<double> r;
  for (size_t i = 0; i < num.size(); ++i) r.push_back(num[i] / den[i]);
  const double mn = std::accumulate(num.begin(), num.end(), 0.0) / double(num.size());
  const double md = std::accumulate(den.begin(), den.end(), 0.0) / double(den.size());
  return {{"ratio_of_means", mn / md},
          {"min", *std::min_element(r.begin(), r.end())},
          {"max", *std::max_element(r.begin(), r.end())}};
}

// Motion (virtual points forward, backward baseline, surface) and the volume instance's geometry (virtual
// points, surface) on a scene generator, over seeds; the volume instance's time and memory next to the
// surface instance's on the first run.
json temporal(gpu::Context& ctx, const GuidingBenchOptions& o, const std::string& name,
              const std::function<json(int, int, int, int, uint32_t)>& scene_at, json* cost_out) {
  const int w = o.width, h = o.height;
  auto frame_scene = [&](int f, bool denoise, const std::string& motion, const std::string& geometry,
                         uint32_t seed) {
    json j = scene_at(w, h, f, o.frames, seed);
    j["denoise"] = {{"surface", {{"enabled", denoise}}},
                    {"volume", {{"enabled", denoise}, {"geometry", geometry}}},
                    {"volume_motion", motion}};
    if (!denoise) j["guiding"]["enabled"] = false;
    return make(j);
  };
  std::vector<std::vector<float>> refs;
  {
    std::unique_ptr<render::Renderer> r;
    for (int f = 0; f < o.frames; ++f) {
      scene::Scene s = frame_scene(f, false, "surface", "surface", 9000 + uint32_t(f));
      if (!r)
        r = std::make_unique<render::Renderer>(ctx, s);
      else
        r->set_scene(s, uint32_t(f));
      r->add_samples(o.spp * o.reference_factor);
      const render::Image img = r->resolve();
      std::vector<float> v(size_t(w) * h * 3);
      for (size_t p = 0; p < size_t(w) * h; ++p)
        for (int c = 0; c < 3; ++c) v[p * 3 + c] = img.data[p * glsl::OUT_STRIDE + glsl::OUT_VOL + c];
      refs.push_back(std::move(v));
    }
  }
  const std::vector<std::pair<std::string, std::string>> runs = {{"virtual_points", "virtual_points"},
                                                                 {"backward", "virtual_points"},
                                                                 {"surface", "virtual_points"},
                                                                 {"virtual_points", "surface"}};
  std::map<std::pair<std::string, std::string>, SequenceFigures> fig;
  for (const auto& [motion, geometry] : runs)
    for (int seed = 1; seed <= std::max(1, o.seeds); ++seed) {
      std::unique_ptr<render::Renderer> r;
      std::vector<std::vector<float>> seq;
      scene::Scene prev;
      double err = 0;
      int n = 0;
      for (int f = 0; f < o.frames; ++f) {
        scene::Scene s = frame_scene(f, true, motion, geometry, uint32_t(seed * 100 + f + 1));
        if (!r)
          r = std::make_unique<render::Renderer>(ctx, s);
        else
          r->set_scene(s, uint32_t(f), &prev);
        prev = s;
        r->add_samples(o.sequence_spp);
        render::Image img = r->resolve();
        seq.emplace_back(&img.volume_denoised->colour[0].x,
                         &img.volume_denoised->colour[0].x + size_t(w) * h * 3);
        const eval::Channels ref{refs[size_t(f)].data(), size_t(w) * h, 3, 0};
        if (f >= 2) err += eval::relmse(denoised_volume_of(img), ref), ++n;
      }
      std::vector<eval::Channels> a, b;
      for (int f = 0; f < o.frames; ++f) {
        a.push_back({seq[size_t(f)].data(), size_t(w) * h, 3, 0});
        b.push_back({refs[size_t(f)].data(), size_t(w) * h, 3, 0});
      }
      auto& fg = fig[{motion, geometry}];
      fg.relmse.push_back(err / n);
      fg.change_relmse.push_back(eval::temporal(a, b).relmse_of_change);
      if (cost_out && motion == "virtual_points" && geometry == "virtual_points" && seed == 1) {
        // Per frame medians of each instance's passes, and its memory by ledger category.
        json cost = json::object();
        for (const std::string inst : {"surface", "volume"}) {
          double ms = 0;
          for (const auto& [pass, st] : r->pass_stats())
            if (pass.rfind("svgf." + inst + ".", 0) == 0) ms += render::median(st.ms);
          uint64_t bytes = 0;
          for (const auto& [cat, by] : ctx.ledger().per_category())
            if (cat.rfind("svgf." + inst + " ", 0) == 0) bytes += by;
          cost[inst] = {{"ms_per_frame", ms}, {"bytes", bytes}};
        }
        cost["volume_over_surface_time"] =
            cost["volume"]["ms_per_frame"].get<double>() / cost["surface"]["ms_per_frame"].get<double>();
        double vm = 0;
        for (const auto& [pass, st] : r->pass_stats())
          if (pass == "volume_motion" || pass == "guide_reproject") vm += render::median(st.ms);
        cost["volume_motion_and_guide_reuse_ms_per_frame"] = vm;
        *cost_out = cost;
      }
    }
  json out = {{"scene", name},
              {"frames", o.frames},
              {"sequence_spp", o.sequence_spp},
              {"reference_spp", o.spp * o.reference_factor},
              {"seeds", std::max(1, o.seeds)}};
  json runs_json = json::object();
  for (const auto& [key, fg] : fig)
    runs_json[fmt::format("motion {}, geometry {}", key.first, key.second)] = {
        {"relmse", summary(fg.relmse)}, {"temporal_relmse_of_change", summary(fg.change_relmse)}};
  out["runs"] = runs_json;
  const auto& vp = fig[{"virtual_points", "virtual_points"}];
  out["relmse_surface_motion_over_virtual_points"] =
      summary_ratio(fig[{"surface", "virtual_points"}].relmse, vp.relmse);
  out["relmse_backward_over_virtual_points"] =
      summary_ratio(fig[{"backward", "virtual_points"}].relmse, vp.relmse);
  out["relmse_surface_geometry_over_virtual_points"] =
      summary_ratio(fig[{"virtual_points", "surface"}].relmse, vp.relmse);
  out["change_surface_geometry_over_virtual_points"] =
      summary_ratio(fig[{"virtual_points", "surface"}].change_relmse, vp.change_relmse);
  return out;
}

}  // namespace

json bench_guiding(gpu::Context& ctx, const GuidingBenchOptions& o) {
  json cost;
  json pan = temporal(ctx, o, "panning shaft", panning_scene, &cost);
  json occ = temporal(ctx, o, "shaft before a moving occluder", occluder_scene, nullptr);
  pan["instances"] = cost;
  return {{"equal_time", {equal_time(ctx, o, false), equal_time(ctx, o, true)}},
          {"volume_denoiser", pan},
          {"volume_occluder", occ}};
}

void print_guiding(const json& j) {
  fmt::print(
      "distance guiding at equal GPU time (volume relMSE, unguided / guided: ratio of the means over seeds, "
      "per-seed range)\n");
  fmt::print("  {:<14}{:>10}{:>10}{:>12}{:>8}{:>8}{:>8}\n", "scene", "spp u", "spp g", "t_g / t_u", "ratio",
             "min", "max");
  for (const auto& e : j["equal_time"]) {
    const auto& r = e["relmse_ratio_unguided_over_guided"];
    fmt::print("  {:<14}{:>10}{:>10}{:>12.2f}{:>8.2f}{:>8.2f}{:>8.2f}\n", e["scene"].get<std::string>(),
               e["unguided_spp"].get<int>(), e["guided_spp"].get<int>(),
               e["guided_over_unguided_time_per_sample"].get<double>(),
               e["relmse_ratio_of_means"].get<double>(), r["min"].get<double>(), r["max"].get<double>());
  }
  for (const char* key : {"volume_denoiser", "volume_occluder"}) {
    const auto& v = j[key];
    fmt::print(
        "volume instance, {} ({} frames of {} spp, {} seeds): denoised volume relMSE (frames 2..) and "
        "temporal relMSE of the change, means over seeds\n",
        v["scene"].get<std::string>(), v["frames"].get<int>(), v["sequence_spp"].get<int>(),
        v["seeds"].get<int>());
    for (const auto& [run, f] : v["runs"].items())
      fmt::print("  {:<44}{:>10.4f}{:>10.4f}\n", run, f["relmse"]["mean"].get<double>(),
                 f["temporal_relmse_of_change"]["mean"].get<double>());
    for (const char* r :
         {"relmse_surface_motion_over_virtual_points", "relmse_backward_over_virtual_points",
          "relmse_surface_geometry_over_virtual_points", "change_surface_geometry_over_virtual_points"})
      fmt::print("  {:<44}{:>10.3f} ({:.3f}..{:.3f} per seed)\n", r, v[r]["ratio_of_means"].get<double>(),
                 v[r]["min"].get<double>(), v[r]["max"].get<double>());
  }
  const auto& c = j["volume_denoiser"]["instances"];
  fmt::print("  svgf.volume / svgf.surface time {:.2f}; memory {:.2f} MB / {:.2f} MB\n",
             c["volume_over_surface_time"].get<double>(), c["volume"]["bytes"].get<double>() / 1e6,
             c["surface"]["bytes"].get<double>() / 1e6);
}

}  // namespace haze::bench
