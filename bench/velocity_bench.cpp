#include "bench/velocity_bench.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <numeric>

#include "bench/bench_util.hpp"
#include "eval/metrics.hpp"
#include "render/renderer.hpp"
#include "render/run.hpp"
#include "scene/scene.hpp"
#include "vdb/vdb.h"

namespace haze::bench {

namespace {

using nlohmann::json;
namespace fs = std::filesystem;

// The sequence's folder, removed when the bench ends (also when it throws).
struct ScratchDir {
  fs::path path = fs::temp_directory_path() / fmt::format("haze_bench_velocity_{}", ::getpid());
  ScratchDir() { fs::create_directories(path); }
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

}  // namespace

json bench_velocity(gpu::Context& ctx, const VelocityBenchOptions& o) {
  ScratchDir dir;
  const double fps = 24;
  vdb::ProceduralSpec spec;
  spec.kind = "cloud";
  spec.voxel_size = 0.04;
  spec.center = {-0.2, 1, 0};
  spec.size = glm::dvec3(1.6);
  spec.density = 3;
  spec.falloff = 0.4;
  spec.frequency = 3;
  std::vector<vdb::ProceduralFile> files;
  for (int f = 0; f < o.frames; ++f)
    files.push_back({(dir.path / fmt::format("smoke_{:04d}.vdb", f)).string(), glm::dvec3(o.move * f, 0, 0)});
  vdb::write_procedural(spec, files, glm::dvec3(o.move * fps, 0, 0));

  auto scene = [&](bool denoise, bool velocity, uint32_t seed) {
    json m = {{"file", (dir.path / "smoke_####.vdb").string()}, {"albedo", {0.95, 0.95, 0.95}}, {"g", 0.3}};
    if (velocity) m["velocity"] = {{"grid", "vel"}, {"unit", "second"}};
    json j = {{"camera", {{"position", {0, 1, 3.2}}, {"target", {0, 1, 0}}, {"fov_y", 40}}},
              {"media", {m}},
              {"lights",
               {{"sun", {{"direction", {-0.4, 1, 0.3}}, {"irradiance", 4}}},
                {"environment", {{"color", {0.05, 0.06, 0.08}}}}}},
              {"render", {{"width", o.width}, {"height", o.height}, {"fps", fps}, {"seed", seed}}},
              {"denoise",
               {{"surface", {{"enabled", false}}},
                {"volume", {{"enabled", denoise}}},
                {"volume_motion", "virtual_points"}}}};
    return scene::from_json(j, "velocity bench scene", "");
  };
  // The reference: each frame converged on its own.
  std::vector<render::Image> refs;
  {
    const scene::Scene s = scene(false, false, 9001);
    std::unique_ptr<render::Renderer> r;
    for (int f = 0; f < o.frames; ++f) {
      render::use_frame(ctx, r, s, f, true);
      r->add_samples(o.reference_spp);
      refs.push_back(r->resolve());
    }
  }
  // Denoised relMSE per seed, mean over the frames that have a history (from the third on).
  std::map<bool, std::vector<double>> err;
  std::vector<double> ratios;
  for (int seed = 1; seed <= o.seeds; ++seed) {
    for (bool velocity : {true, false}) {
      const scene::Scene s = scene(true, velocity, uint32_t(seed));
      std::unique_ptr<render::Renderer> r;
      std::vector<double> e;
      for (int f = 0; f < o.frames; ++f) {
        render::use_frame(ctx, r, s, f, f == 0);
        r->add_samples(o.sequence_spp);
        const render::Image img = r->resolve();
        if (f >= 2) e.push_back(eval::relmse(denoised_volume_of(img), volume_of(refs[size_t(f)])));
      }
      err[velocity].push_back(std::accumulate(e.begin(), e.end(), 0.0) / double(e.size()));
    }
    ratios.push_back(err[false].back() / err[true].back());
  }
  const double mean_v = std::accumulate(err[true].begin(), err[true].end(), 0.0) / o.seeds;
  const double mean_r = std::accumulate(err[false].begin(), err[false].end(), 0.0) / o.seeds;
  return {{"size", {o.width, o.height}},
          {"frames", o.frames},
          {"sequence_spp", o.sequence_spp},
          {"reference_spp", o.reference_spp},
          {"move_per_frame", o.move},
          {"relmse_velocity", summary(err[true])},
          {"relmse_rigid_only", summary(err[false])},
          {"relmse_ratio_rigid_over_velocity", mean_r / mean_v},
          {"relmse_ratio_rigid_over_velocity_per_seed", summary(ratios)}};
}

void print_velocity(const json& j) {
  const auto& r = j["relmse_ratio_rigid_over_velocity_per_seed"];
  fmt::print(
      "volume instance on a moving smoke sequence ({} frames, {} spp, {} units/frame): denoised relMSE "
      "rigid-only / velocity {:.2f} (per seed {:.2f}..{:.2f})\n",
      j["frames"].get<int>(), j["sequence_spp"].get<int>(), j["move_per_frame"].get<double>(),
      j["relmse_ratio_rigid_over_velocity"].get<double>(), r["min"].get<double>(), r["max"].get<double>());
}

}  // namespace haze::bench
