#include "bench/light_choice_bench.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <numeric>

#include "bench/bench_util.hpp"
#include "lights/environment.hpp"
#include "render/renderer.hpp"
#include "scene/scene.hpp"
#include "shaders/glsl.hpp"

namespace haze::bench {

namespace {

using nlohmann::json;

// Per-pixel sample variance of L (summed over RGB) and the mean of L, over the image.
struct Moments {
  double variance = 0, mean = 0;
};
Moments moments(const render::Renderer& r) {
  const std::vector<double> acc = r.accum();
  const size_t pixels = acc.size() / glsl::ACC_STRIDE;
  const double n = r.samples();
  Moments m;
  for (size_t p = 0; p < pixels; ++p)
    for (uint32_t c = 0; c < 3; ++c) {
      const double s = acc[p * glsl::ACC_STRIDE + glsl::ACC_L + c] / n;
      const double s2 = acc[p * glsl::ACC_STRIDE + glsl::ACC_L2 + c] / n;
      m.variance += std::max(0.0, s2 - s * s) * n / (n - 1);
      m.mean += s;
    }
  m.variance /= double(pixels);
  m.mean /= double(pixels);
  return m;
}

// Trace time per sample of renderer a over renderer b, sampled in alternation after one warm-up sample
// each: the ratio of each adjacent pair (they share the machine's load of the moment), summarised over the
// pairs (median, min, max). The 2-core hosts are shared: the pairs spread widely.
json trace_time_ratio(render::Renderer& a, render::Renderer& b, int reps) {
  a.add_samples(1);
  b.add_samples(1);
  std::vector<double> ratios;
  for (int i = 0; i < reps; ++i) {
    a.add_samples(1);
    const double ta = a.pass_stats().at("trace").ms.back();
    b.add_samples(1);
    ratios.push_back(ta / b.pass_stats().at("trace").ms.back());
  }
  json out = summary(ratios);
  out["median"] = render::median(ratios);
  return out;
}

}  // namespace

json bench_light_choice(gpu::Context& ctx, const LightChoiceBenchOptions& o) {
  auto room = [&](const char* choice, uint32_t seed) {
    json points = json::array();
    // The dim lights on a ring, the bright one off-centre, all above the haze: no light inside the medium,
    // where a distance sampled close to one light would weigh its 1 / r^2 by the other light's choice.
    for (int k = 0; k < o.dim_lights; ++k) {
      const double a = 2 * M_PI * k / o.dim_lights;
      points.push_back({{"position", {1.6 * std::cos(a), 1.9, 1.6 * std::sin(a)}}, {"intensity", o.dim}});
    }
    points.push_back({{"position", {0.6, 1.7, -0.4}}, {"intensity", o.bright}, {"color", {1, 0.9, 0.8}}});
    json j = {{"camera", {{"position", {0, 1, 4.5}}, {"target", {0, 0.8, 0}}, {"fov_y", 50}}},
              {"haze",
               {{"sigma_t", 0.25},
                {"albedo", {0.9, 0.9, 0.9}},
                {"g", 0.2},
                {"bounded", true},
                {"bounds_min", {-2, 0, -2}},
                {"bounds_max", {2, 1.4, 2}}}},
              {"surfaces",
               {{{"mesh", {{"kind", "plane"}, {"size", {6, 6}}}},
                 {"albedo", {0.6, 0.6, 0.6}},
                 {"transform", {{"rotate", {-90, 0, 0}}}}}}},
              {"lights", {{"points", points}, {"choice", choice}}},
              {"render", {{"width", o.width}, {"height", o.height}, {"seed", seed}, {"max_depth", 1}}},
              {"denoise", {{"surface", {{"enabled", false}}}, {"volume", {{"enabled", false}}}}}};
    return j;
  };
  auto scene = [&](const char* choice, uint32_t seed) {
    return scene::from_json(room(choice, seed), "light choice bench scene", "");
  };
  std::vector<double> ratios, mean_diffs;
  std::vector<double> var_uniform, var_power;
  for (int seed = 1; seed <= o.seeds; ++seed) {
    Moments m[2];
    int k = 0;
    for (const char* choice : {"uniform", "power"}) {
      render::Renderer r(ctx, scene(choice, uint32_t(seed)));
      r.add_samples(o.spp);
      m[k++] = moments(r);
    }
    var_uniform.push_back(m[0].variance);
    var_power.push_back(m[1].variance);
    ratios.push_back(m[0].variance / m[1].variance);
    mean_diffs.push_back(m[1].mean / m[0].mean - 1);
  }
  // What the choice costs: trace time per sample, power / uniform, on the same scene.
  json choice_time;
  {
    render::Renderer power(ctx, scene("power", 1)), uniform(ctx, scene("uniform", 1));
    choice_time = trace_time_ratio(power, uniform, o.time_reps);
  }

  // What a map's code costs: the room lit by a 512 x 256 map of one radiance, against the constant
  // environment of that radiance. Both send the same radiance from every direction and draw directions
  // uniformly over the sphere (the map's sampler with a constant map is uniform in solid angle), so the
  // ratio is the sampler's two binary searches and the texel lookups alone.
  const std::filesystem::path map_file =
      std::filesystem::temp_directory_path() / fmt::format("haze_bench_sky_{}.exr", ::getpid());
  struct {
    uint32_t width = 512, height = 256;
  } sky;
  const glm::vec3 radiance(0.4f, 0.5f, 0.7f);
  lights::EnvironmentMap map;
  map.width = sky.width;
  map.height = sky.height;
  map.texels.assign(size_t(map.width) * map.height, radiance);
  lights::write_environment_map(map_file.string(), map);
  json env_time;
  try {
    std::vector<scene::Scene> scenes;
    for (bool with_map : {true, false}) {
      json j = room("power", 1);
      const json env = with_map ? json{{"file", map_file.string()}}
                                : json{{"color", {radiance.r, radiance.g, radiance.b}}};
      j["lights"] = {{"environment", env}};
      scenes.push_back(scene::from_json(j, "light choice bench scene", ""));
    }
    render::Renderer with_map(ctx, scenes[0]), constant(ctx, scenes[1]);
    env_time = trace_time_ratio(with_map, constant, o.time_reps);
  } catch (...) {
    std::error_code ec;
    std::filesystem::remove(map_file, ec);
    throw;
  }
  std::error_code ec;
  std::filesystem::remove(map_file, ec);

  const double mu = std::accumulate(var_uniform.begin(), var_uniform.end(), 0.0);
  const double mp = std::accumulate(var_power.begin(), var_power.end(), 0.0);
  return {{"size", {o.width, o.height}},
          {"spp", o.spp},
          {"lights", {{"bright", o.bright}, {"dim", o.dim}, {"dim_count", o.dim_lights}}},
          {"variance_uniform", summary(var_uniform)},
          {"variance_power", summary(var_power)},
          {"variance_ratio_uniform_over_power", mu / mp},
          {"variance_ratio_uniform_over_power_per_seed", summary(ratios)},
          {"mean_power_over_uniform_minus_1", summary(mean_diffs)},
          {"trace_time_ratio_power_over_uniform", choice_time},
          {"trace_time_ratio_map_over_constant", env_time},
          {"map_size", {sky.width, sky.height}}};
}

void print_light_choice(const json& j) {
  const auto& r = j["variance_ratio_uniform_over_power_per_seed"];
  const auto& d = j["mean_power_over_uniform_minus_1"];
  const auto& c = j["trace_time_ratio_power_over_uniform"];
  const auto& e = j["trace_time_ratio_map_over_constant"];
  fmt::print(
      "light choice, one bright and {} dim point lights in haze ({} spp): per-pixel variance uniform / power "
      "{:.2f} (per seed {:.2f}..{:.2f}); image mean power / uniform - 1 in {:.2g}..{:.2g}\n",
      j["lights"]["dim_count"].get<int>(), j["spp"].get<int>(),
      j["variance_ratio_uniform_over_power"].get<double>(), r["min"].get<double>(), r["max"].get<double>(),
      d["min"].get<double>(), d["max"].get<double>());
  fmt::print(
      "  trace time per sample, median of adjacent pairs: power / uniform choice {:.3f} ({:.2f}..{:.2f}); "
      "lit by "
      "a constant {}x{} map / by the constant environment {:.3f} ({:.2f}..{:.2f})\n",
      c["median"].get<double>(), c["min"].get<double>(), c["max"].get<double>(), j["map_size"][0].get<int>(),
      j["map_size"][1].get<int>(), e["median"].get<double>(), e["min"].get<double>(), e["max"].get<double>());
}

}  // namespace haze::bench
