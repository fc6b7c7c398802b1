#include "bench/volume_repr_bench.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "bench/bench_util.hpp"
#include "render/renderer.hpp"
#include "shaders/glsl.hpp"

namespace haze::bench {

namespace {

// Push constants of shaders/bench/volume_repr.comp.
struct ReprPush {
  uint32_t count, n, grid, seed;
  glm::vec4 lo, hi;
  glm::ivec4 dense_origin, dense_dims;
};
static_assert(sizeof(ReprPush) == 80);

glm::vec3 domain_point(const ReprGrid& g, uint32_t& rng) {
  // Components drawn in order x, y, z like the kernel's vec3(rng_next(), rng_next(), rng_next()).
  float ux = glsl::rng_next(rng), uy = glsl::rng_next(rng), uz = glsl::rng_next(rng);
  return g.lo + (g.hi - g.lo) * glm::vec3(ux, uy, uz);
}

}  // namespace

std::vector<glm::vec3> repr_points(const ReprGrid& g, bool march, uint32_t i, uint32_t n, uint32_t seed) {
  uint32_t rng = glsl::rng_init(seed, i, 0u);
  std::vector<glm::vec3> p;
  if (march) {
    glm::vec3 a = domain_point(g, rng);
    glm::vec3 b = domain_point(g, rng);
    for (uint32_t k = 0; k < n; ++k) p.push_back(a + (b - a) * ((float(k) + 0.5f) / float(n)));
  } else {
    for (uint32_t k = 0; k < n; ++k) p.push_back(domain_point(g, rng));
  }
  return p;
}

VolumeReprKernels::VolumeReprKernels(gpu::Context& ctx) : ctx_(ctx) {
  for (int dense = 0; dense < 2; ++dense)
    for (int march = 0; march < 2; ++march) {
      // medium.glsl's scene, media and majorant bindings are declared but never read here.
      gpu::KernelDecl d("bench/volume_repr.comp");
      if (dense) d.define("HAZE_DENSE");
      d.buffer("scene").buffer("grids").buffer("media").buffer("majorant").buffer("dense").buffer("result");
      kernels_[dense][march] =
          gpu::Kernel(ctx, std::move(d.push(sizeof(ReprPush)).specialize({uint32_t(march)})));
    }
  placeholder_ = gpu::Buffer(ctx, "bench volume_repr placeholder", "benchmark",
                             std::max(sizeof(glsl::GpuScene), sizeof(glsl::GpuMedium)), "unused");
  placeholder_.fill_zero();
}

VolumeReprKernels::~VolumeReprKernels() = default;

ReprGrid VolumeReprKernels::upload(const vdb::DeviceGrid& grid, const std::string& name) const {
  if (grid.background != 0.f)
    throw std::runtime_error(
        fmt::format("bench volume_repr: grid '{}' has background {}; the dense array "
                    "assumes 0",
                    name, grid.background));
  ReprGrid g;
  g.name = name;
  g.origin = grid.index_min - 1;
  g.dims = grid.index_max - grid.index_min + 3;
  g.lo = glm::vec3(g.origin);
  g.hi = glm::vec3(g.origin + g.dims - 1);
  g.active_voxels = grid.active_voxels;
  const size_t voxels = size_t(g.dims.x) * g.dims.y * g.dims.z;
  std::vector<float> dense(voxels);
  vdb::Sampler sampler(grid);
  for (int z = 0; z < g.dims.z; ++z)
    for (int y = 0; y < g.dims.y; ++y)
      for (int x = 0; x < g.dims.x; ++x)
        dense[(size_t(z) * g.dims.y + y) * g.dims.x + x] = sampler.voxel(g.origin + glm::ivec3(x, y, z));
  g.nanovdb_bytes = grid.nanovdb.size();
  g.dense_bytes = voxels * sizeof(float);
  g.nanovdb =
      gpu::Buffer(ctx_, fmt::format("bench {} nanovdb", name), "benchmark", g.nanovdb_bytes, "NanoVDB");
  g.nanovdb.upload(grid.nanovdb);
  const uint64_t a = g.nanovdb.device_address();
  g.table =
      gpu::Buffer(ctx_, fmt::format("bench {} grid address", name), "benchmark", 8, "u64 device address");
  g.table.upload(std::vector<glm::uvec2>{{uint32_t(a), uint32_t(a >> 32)}});
  g.dense =
      gpu::Buffer(ctx_, fmt::format("bench {} dense", name), "benchmark", g.dense_bytes, "f32 x-fastest");
  g.dense.upload(dense);
  return g;
}

void VolumeReprKernels::record(VkCommandBuffer cmd, const ReprGrid& g, bool dense, bool march, uint32_t count,
                               uint32_t n, uint32_t seed, const gpu::Buffer& out) const {
  ReprPush push{count,
                n,
                0u,
                seed,
                glm::vec4(g.lo, 0),
                glm::vec4(g.hi, 0),
                glm::ivec4(g.origin, 0),
                glm::ivec4(g.dims, 0)};
  gpu::Bindings b;
  b.set("scene", placeholder_).set("grids", g.table).set("media", placeholder_).set("majorant", placeholder_);
  b.set("dense", g.dense).set("result", out);
  const gpu::Kernel& k = kernels_[dense][march];
  k.dispatch_1d(cmd, b, &push, count);
}

std::vector<float> VolumeReprKernels::run(const ReprGrid& g, bool dense, bool march, uint32_t count,
                                          uint32_t n, uint32_t seed) const {
  gpu::Buffer out(ctx_, "bench volume_repr sums", "benchmark", uint64_t(count) * 4, "f32");
  ctx_.submit_and_wait([&](VkCommandBuffer cmd) { record(cmd, g, dense, march, count, n, seed, out); });
  return out.download_vector<float>();
}

double max_relative_difference(const std::vector<float>& a, const std::vector<float>& b) {
  if (a.size() != b.size()) return INFINITY;
  double scale = 0;
  for (float v : b) scale = std::max(scale, std::abs(double(v)));
  const double floor = 1e-6 * scale;
  double worst = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double x = a[i], y = b[i];
    if (!std::isfinite(x) || !std::isfinite(y)) return INFINITY;
    const double d = std::abs(x - y) / std::max({std::abs(x), std::abs(y), floor, 1e-30});
    worst = std::max(worst, d);
  }
  return worst;
}

namespace {

// The dense-ish grid is the bench scene's cloud; the sparse one a ragged cloud (noise amplitude 1, one
// octave) whose active voxels fill about an eighth of their bounding box.
struct ReprSpec {
  std::string id, what;
  vdb::ProceduralSpec spec;
};
std::vector<ReprSpec> repr_specs() {
  vdb::ProceduralSpec cloud;
  cloud.kind = "cloud";
  cloud.voxel_size = 0.06;
  cloud.center = {0, 4, 0};
  cloud.size = glm::dvec3(5);
  cloud.density = 4;
  cloud.falloff = 0.6;
  cloud.frequency = 1.2;
  cloud.seed = 3;
  vdb::ProceduralSpec sparse = cloud;
  sparse.center = glm::dvec3(0);
  sparse.falloff = 1.0;
  sparse.frequency = 1.5;
  sparse.octaves = 1;
  sparse.seed = 11;
  return {{"cloud", "the bench scene's cloud (dense-ish)", cloud},
          {"sparse", "a ragged cloud: noise amplitude 1, one octave (sparse)", sparse}};
}

}  // namespace

nlohmann::json bench_volume_repr(gpu::Context& ctx, const VolumeReprOptions& o) {
  VolumeReprKernels kernels(ctx);
  gpu::Buffer out_a(ctx, "bench volume_repr sums (nanovdb)", "benchmark", uint64_t(o.invocations) * 4, "f32");
  gpu::Buffer out_b(ctx, "bench volume_repr sums (dense)", "benchmark", uint64_t(o.invocations) * 4, "f32");
  nlohmann::json grids = nlohmann::json::array();
  const uint32_t seed = 17;
  for (const auto& [name, what, spec] : repr_specs()) {
    vdb::DeviceGrid dg = vdb::make_procedural(spec);
    ReprGrid g = kernels.upload(dg, name);
    const double bbox_voxels = double(dg.index_max.x - dg.index_min.x + 1) *
                               double(dg.index_max.y - dg.index_min.y + 1) *
                               double(dg.index_max.z - dg.index_min.z + 1);
    nlohmann::json e = {{"name", name},
                        {"what", what},
                        {"spec", vdb::to_json(spec)},
                        {"dense_dims", {g.dims.x, g.dims.y, g.dims.z}},
                        {"active_voxels", g.active_voxels},
                        {"active_fraction_of_bbox", double(g.active_voxels) / bbox_voxels},
                        {"nanovdb_bytes", g.nanovdb_bytes},
                        {"dense_bytes", g.dense_bytes},
                        {"memory_ratio_nanovdb_over_dense", double(g.nanovdb_bytes) / double(g.dense_bytes)}};
    double worst = 0;
    for (bool march : {false, true}) {
      const uint32_t n = march ? o.march_steps : o.lookups;
      auto ms = timed_medians(
          ctx, o.reps,
          {[&](VkCommandBuffer cmd) { kernels.record(cmd, g, false, march, o.invocations, n, seed, out_a); },
           [&](VkCommandBuffer cmd) { kernels.record(cmd, g, true, march, o.invocations, n, seed, out_b); }});
      // Same seed, same points: the sums must agree.
      const double diff =
          max_relative_difference(out_a.download_vector<float>(), out_b.download_vector<float>());
      worst = std::max(worst, diff);
      const double lookups = double(o.invocations) * n;
      e[march ? "march" : "lookups"] = {{"lookups_per_invocation", n},
                                        {"invocations", o.invocations},
                                        {"nanovdb_ms", ms[0]},
                                        {"dense_ms", ms[1]},
                                        {"nanovdb_lookups_per_s", lookups / (ms[0] * 1e-3)},
                                        {"dense_lookups_per_s", lookups / (ms[1] * 1e-3)},
                                        {"time_ratio_nanovdb_over_dense", ms[0] / ms[1]},
                                        {"max_relative_difference", diff}};
    }
    e["max_relative_difference"] = worst;
    if (!(worst <= 1e-4))
      throw std::runtime_error(
          fmt::format("bench volume_repr: the NanoVDB and dense kernels disagree on grid '{}': max relative "
                      "difference {:.3g} "
                      "> 1e-4",
                      name, worst));
    grids.push_back(e);
  }
  return {{"grids", grids}, {"reps", o.reps}};
}

void print_volume_repr(const nlohmann::json& j) {
  fmt::print(
      "PNanoVDB against a dense float array of the same grid (trilinear lookups; ratios nanovdb / dense)\n");
  fmt::print("  {:<8}{:>9}{:>12}{:>11}{:>9}{:>11}{:>10}{:>11}\n", "grid", "active", "NanoVDB MB", "dense MB",
             "memory", "t random", "t march", "max rel d");
  for (const auto& e : j["grids"])
    fmt::print("  {:<8}{:>8.0f}%{:>12.2f}{:>11.2f}{:>9.3f}{:>11.2f}{:>10.2f}{:>11.1e}\n",
               e["name"].get<std::string>(), 100 * e["active_fraction_of_bbox"].get<double>(),
               e["nanovdb_bytes"].get<double>() / 1e6, e["dense_bytes"].get<double>() / 1e6,
               e["memory_ratio_nanovdb_over_dense"].get<double>(),
               e["lookups"]["time_ratio_nanovdb_over_dense"].get<double>(),
               e["march"]["time_ratio_nanovdb_over_dense"].get<double>(),
               e["max_relative_difference"].get<double>());
  for (const auto& e : j["grids"])
    fmt::print("  {}: {}; NanoVDB {:.3g} / dense {:.3g} random lookups per s\n", e["name"].get<std::string>(),
               e["what"].get<std::string>(), e["lookups"]["nanovdb_lookups_per_s"].get<double>(),
               e["lookups"]["dense_lookups_per_s"].get<double>());
}

}  // namespace haze::bench
