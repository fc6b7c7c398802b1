#include "bench/efficiency_bench.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <stdexcept>

#include "eval/metrics.hpp"
#include "render/renderer.hpp"
#include "scene/scene.hpp"

namespace haze::bench {

namespace {

using nlohmann::json;

// One comparison: the scene (without estimator, guiding or seed), its size and the samples per pixel of the
// side measured first; `a` and `b` patch the scene into the two sides (a over b: > 1 means a wins).
struct Case {
  std::string name, what;
  json scene;
  int width, height, spp;
  json a, b;
  std::string a_name, b_name;
};

Case make_case(std::string name, std::string what, json scene, int width, int height, int spp, json a, json b,
               std::string a_name, std::string b_name) {
  return {std::move(name), std::move(what),   std::move(scene), width, height, spp, std::move(a),
          std::move(b),    std::move(a_name), std::move(b_name)};
}

json base(int w, int h, int max_depth) {
  return {{"render", {{"width", w}, {"height", h}, {"max_depth", max_depth}}},
          {"denoise", {{"surface", {{"enabled", false}}}, {"volume", {{"enabled", false}}}}}};
}

const json kDefault = {{"render", {{"estimator", "default"}}}};
const json kVolpath = {{"render", {{"estimator", "volpath"}}}};

// (a) A dense sunlit cloud: 2 units across, sigma_t up to 8 per unit, albedo 0.9, g 0.5, multiple scattering
// to depth 100 (the comparison with pbrt-v4).
Case dense_cloud(double s) {
  const int w = int(std::lround(128 * s)), h = w;
  json j = base(w, h, 100);
  j["camera"] = {{"position", {0, 0.4, 3.6}}, {"target", {0, 0, 0}}, {"fov_y", 38}};
  j["media"] = {{{"procedural",
                  {{"kind", "cloud"},
                   {"voxel_size", 0.04},
                   {"center", {0, 0, 0}},
                   {"size", {2, 2, 2}},
                   {"density", 8},
                   {"falloff", 0.5},
                   {"seed", 3}}},
                 {"albedo", {0.9, 0.9, 0.9}},
                 {"g", 0.5}}};
  j["lights"] = {{"sun", {{"direction", {0.5, 0.8, 0.3}}, {"irradiance", 4}}}};
  return make_case("dense_cloud", "dense sunlit cloud (sigma_t to 8, albedo 0.9, g 0.5, depth 100)", j, w, h,
                   8, kDefault, kVolpath, "default", "volpath");
}

// Slabs of a ceiling at y = 3 (box of size sx x 0.1 x sz centred at (cx, 3.05, cz)).
json slab(double cx, double cz, double sx, double sz) {
  return {{"mesh", {{"kind", "box"}, {"size", {sx, 0.1, sz}}}},
          {"transform", {{"translate", {cx, 3.05, cz}}}}};
}

// (b) A thin shaft of sunlight through a 1 x 1 opening into haze, seen from the side.
Case haze_shaft(double s) {
  const int w = int(std::lround(128 * s)), h = int(std::lround(72 * s));
  json j = base(w, h, 2);
  j["camera"] = {{"position", {0, 1, 0}}, {"target", {0, 1.2, 1}}, {"fov_y", 50}};
  j["surfaces"] = {slab(-10.25, 5, 19.5, 30), slab(10.25, 5, 19.5, 30), slab(0, -2.25, 1, 15.5),
                   slab(0, 13.25, 1, 13.5)};
  j["haze"] = {{"sigma_t", 0.1},
               {"albedo", {0.9, 0.9, 0.9}},
               {"bounded", true},
               {"bounds_min", {-20, -1, 0}},
               {"bounds_max", {20, 3, 12}}};
  j["lights"] = {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", 5}, {"angular_diameter", 0}}}};
  return make_case("haze_shaft", "thin sunlit shaft in haze (1 x 1 opening, depth 2)", j, w, h, 32, kDefault,
                   kVolpath, "default", "volpath");
}

// (c) A point light inside a box of homogeneous medium, seen from outside; single scattering (with more,
// NEE to the light from walk vertices near it has infinite variance, 1/r^2, in both estimators, and relMSE
// over a few seeds is a lottery).
Case point_in_box(double s) {
  const int w = int(std::lround(96 * s)), h = w;
  json j = base(w, h, 1);
  j["camera"] = {{"position", {0.3, 0.5, 3.5}}, {"target", {0, 0, 0}}, {"fov_y", 45}};
  j["haze"] = {{"sigma_t", 0.8},  {"albedo", {0.8, 0.8, 0.8}},  {"g", 0.3},
               {"bounded", true}, {"bounds_min", {-1, -1, -1}}, {"bounds_max", {1, 1, 1}}};
  j["lights"] = {{"points", {{{"position", {0.2, 0.1, -0.1}}, {"intensity", 3}}}}};
  return make_case("point_in_box", "point light inside a box medium (sigma_t 0.8, albedo 0.8, depth 1)", j, w,
                   h, 32, kDefault, kVolpath, "default", "volpath");
}

// (d) A cloud lit by a constant environment only (haze has no environment maps yet).
Case env_cloud(double s) {
  const int w = int(std::lround(96 * s)), h = w;
  json j = base(w, h, 32);
  j["camera"] = {{"position", {0, 0.3, 3.6}}, {"target", {0, 0, 0}}, {"fov_y", 38}};
  j["media"] = {{{"procedural",
                  {{"kind", "cloud"},
                   {"voxel_size", 0.04},
                   {"center", {0, 0, 0}},
                   {"size", {2, 2, 2}},
                   {"density", 3},
                   {"falloff", 0.5},
                   {"seed", 5}}},
                 {"albedo", {0.95, 0.95, 0.95}},
                 {"g", 0.3}}};
  j["lights"] = {{"environment", {{"color", {0.5, 0.6, 0.8}}, {"intensity", 1}}}};
  return make_case("env_cloud", "cloud lit by a constant environment (sigma_t to 3, albedo 0.95, depth 32)",
                   j, w, h, 16, kDefault, kVolpath, "default", "volpath");
}

// (e) Sheets of sunlight through a row of planks into haze: the camera looks along the row, so each of its
// rays crosses several sheets. Guided (the renderer's default P) over unguided, both the default estimator.
Case sheets(double s) {
  const int w = int(std::lround(128 * s)), h = int(std::lround(72 * s));
  json j = base(w, h, 1);
  j["camera"] = {{"position", {0, 1, 0}}, {"target", {0, 1.3, 1}}, {"fov_y", 50}};
  json planks = json::array();
  planks.push_back(slab(0, -4, 20, 10));  // closed ceiling before the row
  const double width = 0.8, gap = 0.4;
  double z = 1;
  for (int k = 0; k < 10; ++k, z += width + gap) planks.push_back(slab(0, z + 0.5 * width, 20, width));
  planks.push_back(slab(0, z + 5, 20, 10));  // and after it
  j["surfaces"] = planks;
  j["haze"] = {{"sigma_t", 0.1},
               {"albedo", {0.9, 0.9, 0.9}},
               {"bounded", true},
               {"bounds_min", {-10, -1, 0}},
               {"bounds_max", {10, 3, 16}}};
  j["lights"] = {{"sun", {{"direction", {0, 1, 0.25}}, {"irradiance", 5}, {"angular_diameter", 0}}}};
  return make_case("sheets", "sheets of sunlight through 10 slits between planks into haze (depth 1)", j, w,
                   h, 32, {{"guiding", {{"enabled", true}}}}, {{"guiding", {{"enabled", false}}}}, "guided",
                   "unguided");
}

scene::Scene make(json j, const json& side, uint32_t seed) {
  j.merge_patch(side);
  j["render"]["seed"] = seed;
  return scene::from_json(j, "efficiency bench scene", "");
}

// The resolved radiance (rgb per pixel) and its sample variance of the mean.
struct Render {
  std::vector<float> L, var_of_mean;
  double trace_ms = 0;
  render::FrameCounters counters;
  json walk_splits;  // render.walk_splits 0: the learned K* and its statistics
};

Render resolved(render::Renderer& r, int spp) {
  const render::Image img = r.resolve();
  Render out;
  const size_t pixels = size_t(img.width) * img.height;
  for (size_t p = 0; p < pixels; ++p)
    for (uint32_t c = 0; c < 3; ++c) {
      out.L.push_back(img.data[p * glsl::OUT_STRIDE + glsl::OUT_L + c]);
      out.var_of_mean.push_back(img.data[p * glsl::OUT_STRIDE + glsl::OUT_VAR + c] / float(spp));
    }
  for (double ms : r.pass_stats().at("trace").ms) out.trace_ms += ms;
  out.counters = img.counters;
  out.walk_splits = r.walk_splits_stats();
  return out;
}

Render render_case(gpu::Context& ctx, const scene::Scene& s, int spp) {
  render::Renderer r(ctx, s);
  r.add_samples(spp);
  return resolved(r, spp);
}

// Both sides of one seed in kRounds alternating blocks of about equal time (a's samples in equal parts, b's
// likewise), so that the machine's drift over the render touches both alike. Each switch to the other side
// costs the next dispatch: on lavapipe a shaft dispatch of volpath took 3.1 ms in a run of its own and 4.2 ms
// right after one of the default's. Alternating one dispatch at a time charged that to every dispatch of the
// side with fewer samples and to fewer of the other's; blocks charge both kRounds times, a few percent.
std::pair<Render, Render> render_pair(gpu::Context& ctx, const scene::Scene& a, int spp_a,
                                      const scene::Scene& b, int spp_b) {
  constexpr int kRounds = 4;
  render::Renderer ra(ctx, a), rb(ctx, b);
  for (int r = 1; r <= kRounds; ++r) {
    ra.add_samples(spp_a * r / kRounds - spp_a * (r - 1) / kRounds);
    rb.add_samples(spp_b * r / kRounds - spp_b * (r - 1) / kRounds);
  }
  return {resolved(ra, spp_a), resolved(rb, spp_b)};
}

// Mean GPU time of one trace dispatch over `n` samples, after warm-up samples: lavapipe compiles a pipeline
// at its first dispatch, and learned walk splits take two walks until their statistics hold variances (the
// third dispatch); timed from there, the equal-time sample count of b is that of a's steady state (the
// dispatches after those still learning, and exploring two walks where K rounds to 1, are part of it).
double ms_per_sample(gpu::Context& ctx, const scene::Scene& s, int n) {
  render::Renderer r(ctx, s);
  r.add_samples(int(glsl::SPLIT_EXPLORE));
  const size_t warm = r.pass_stats().at("trace").ms.size();
  r.add_samples(n);
  const auto& ms = r.pass_stats().at("trace").ms;
  return std::accumulate(ms.begin() + long(warm), ms.end(), 0.0) / double(ms.size() - warm);
}

json side_json(const std::vector<double>& relmse, const std::vector<double>& ms, int spp,
               const render::FrameCounters& c, double pixels, const json& walk_splits) {
  const double samples = pixels * spp * double(relmse.size());
  json j = {{"spp", spp},
            {"relmse", relmse},
            {"trace_ms", ms},
            {"lookups_per_sample", double(c.lookups) / samples},
            {"real_collisions_per_sample", double(c.delta_real) / samples},
            {"null_share", c.null_share()},
            {"discarded", c.discarded_json()}};
  if (!walk_splits.empty()) j["walk_splits"] = walk_splits;  // per seed
  return j;
}

double mean(const std::vector<double>& v) {
  return std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
}

json run_case(gpu::Context& ctx, const Case& c, const EfficiencyOptions& o) {
  // Sample counts at about equal time: a gets c.spp, b as many as fit in a's time per sample.
  const double ms_a = ms_per_sample(ctx, make(c.scene, c.a, 1), 2);
  const double ms_b = ms_per_sample(ctx, make(c.scene, c.b, 1), 2);
  const int spp_a = std::max(1, int(std::lround(c.spp * o.scale)));
  const int spp_b = std::max(1, int(std::lround(spp_a * ms_a / ms_b)));
  // The reference: the default estimator (unguided) at reference_factor times a's samples, its own seed.
  const int ref_spp = spp_a * o.reference_factor;
  const Render ref = render_case(ctx, make(c.scene, kDefault, 4000000007u), ref_spp);
  std::vector<double> err_a, err_b, t_a, t_b, ratios;
  json splits_a = json::array(), splits_b = json::array();
  render::FrameCounters counters = ref.counters, counters_a, counters_b;
  for (int seed = 1; seed <= o.seeds; ++seed) {
    const auto [a, b] = render_pair(ctx, make(c.scene, c.a, uint32_t(seed)), spp_a,
                                    make(c.scene, c.b, uint32_t(seed)), spp_b);
    err_a.push_back(relmse_corrected(a.L, ref.L, ref.var_of_mean));
    err_b.push_back(relmse_corrected(b.L, ref.L, ref.var_of_mean));
    t_a.push_back(a.trace_ms);
    t_b.push_back(b.trace_ms);
    ratios.push_back((err_b.back() * t_b.back()) / (err_a.back() * t_a.back()));
    counters_a += a.counters;
    counters_b += b.counters;
    if (!a.walk_splits.empty()) splits_a.push_back(a.walk_splits);
    if (!b.walk_splits.empty()) splits_b.push_back(b.walk_splits);
  }
  // Efficiency 1 / (relMSE x time): a over b is b's mean relMSE x mean time over a's.
  const double ratio = (mean(err_b) * mean(t_b)) / (mean(err_a) * mean(t_a));
  counters += counters_a;
  counters += counters_b;
  const double pixels = double(c.width) * c.height;
  return {{"case", c.name},
          {"what", c.what},
          {"size", {c.width, c.height}},
          {"sides", {c.a_name, c.b_name}},
          {c.a_name, side_json(err_a, t_a, spp_a, counters_a, pixels, splits_a)},
          {c.b_name, side_json(err_b, t_b, spp_b, counters_b, pixels, splits_b)},
          {"time_per_sample_b_over_a", ms_b / ms_a},
          {"reference_spp", ref_spp},
          {"reference_trace_ms", ref.trace_ms},
          {"efficiency_ratio", ratio},
          {"per_seed_ratio_min", *std::min_element(ratios.begin(), ratios.end())},
          {"per_seed_ratio_max", *std::max_element(ratios.begin(), ratios.end())},
          {"discarded", counters.discarded_json()}};
}

}  // namespace

double relmse_corrected(const std::vector<float>& x, const std::vector<float>& ref,
                        const std::vector<float>& ref_var) {
  double sum = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    const double d = double(x[i]) - double(ref[i]);
    sum += (d * d - double(ref_var[i])) / eval::relmse_denominator(ref[i]);
  }
  return x.empty() ? 0.0 : sum / double(x.size());
}

const std::vector<std::string>& efficiency_case_names() {
  static const std::vector<std::string> names = {"dense_cloud", "haze_shaft", "point_in_box", "env_cloud",
                                                 "sheets"};
  return names;
}

namespace {
Case make_efficiency_case(const std::string& name, double scale) {
  return name == "dense_cloud"    ? dense_cloud(scale)
         : name == "haze_shaft"   ? haze_shaft(scale)
         : name == "point_in_box" ? point_in_box(scale)
         : name == "env_cloud"    ? env_cloud(scale)
                                  : sheets(scale);
}
}  // namespace

json efficiency_case_scene(const std::string& name, double scale) {
  return make_efficiency_case(name, scale).scene;
}

json bench_efficiency(gpu::Context& ctx, const EfficiencyOptions& o) {
  json out = {{"seeds", o.seeds},
              {"reference_factor", o.reference_factor},
              {"scale", o.scale},
              {"set_a", o.set_a},
              {"cases", json::array()}};
  for (const std::string& name : efficiency_case_names()) {
    if (!o.cases.empty() && std::find(o.cases.begin(), o.cases.end(), name) == o.cases.end()) continue;
    Case c = make_efficiency_case(name, o.scale);
    c.a.merge_patch(o.set_a);
    out["cases"].push_back(run_case(ctx, c, o));
  }
  return out;
}

void print_efficiency(const json& j) {
  fmt::print(
      "estimator efficiency 1 / (relMSE x trace time) against a converged reference, over {} seeds (ratio of "
      "means; per-seed range)\n",
      j["seeds"].get<int>());
  if (j.contains("set_a") && !j["set_a"].empty()) fmt::print("  side a with {}\n", j["set_a"].dump());
  fmt::print("  {:<14}{:>10}{:>8}{:>8}{:>8}{:>8}{:>12}{:>12}\n", "case", "a / b", "min", "max", "spp a",
             "spp b", "relMSE a", "relMSE b");
  for (const auto& c : j["cases"]) {
    const auto sides = c["sides"];
    const auto& a = c[sides[0].get<std::string>()];
    const auto& b = c[sides[1].get<std::string>()];
    auto m = [](const json& v) { return mean(v.get<std::vector<double>>()); };
    fmt::print("  {:<14}{:>10.2f}{:>8.2f}{:>8.2f}{:>8}{:>8}{:>12.3g}{:>12.3g}  ({} / {})\n",
               c["case"].get<std::string>(), c["efficiency_ratio"].get<double>(),
               c["per_seed_ratio_min"].get<double>(), c["per_seed_ratio_max"].get<double>(),
               a["spp"].get<int>(), b["spp"].get<int>(), m(a["relmse"]), m(b["relmse"]),
               sides[0].get<std::string>(), sides[1].get<std::string>());
  }
}

}  // namespace haze::bench
