// NanoVDB grids on the device (volume/media.hpp, shaders/volume/grids.glsl): grids reached through their
// device addresses, beyond lavapipe's 128 MiB maxStorageBufferRange, looked up by the tracker's own
// sample_medium (shaders/volume/probe.comp) and compared with NanoVDB's CPU sampler. Thresholds were fixed
// before looking.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "gpu/kernel.hpp"
#include "test_util.hpp"
#include "vdb/vdb.h"
#include "volume/media.hpp"

namespace haze::test {
namespace {

using nlohmann::json;

json cloud(double size, double x, uint32_t seed) {
  return {{"procedural",
           {{"kind", "cloud"},
            {"voxel_size", 0.01},
            {"center", {x, 0, 0}},
            {"size", size},
            {"density", 3},
            {"falloff", 0.1},
            {"frequency", 2},
            {"octaves", 1},
            {"seed", seed}}},
          {"density_scale", 1.5}};
}

// sigma_t at `points` through volume/probe.comp (the tracker's sample_medium) on the media of `m`.
std::vector<float> probe(const volume::Media& m, const std::vector<glm::vec4>& points) {
  gpu::Context& ctx = context();
  glsl::GpuScene g{};
  m.fill(g);
  gpu::Buffer scene(ctx, "test scene", "test", sizeof(g), "GpuScene");
  scene.upload(&g, sizeof(g));
  gpu::Buffer pts(ctx, "test probe points", "test", points.size() * 16, "vec4");
  pts.upload(points);
  gpu::Buffer sigma(ctx, "test probe sigma", "test", points.size() * 4, "f32");
  gpu::KernelDecl d("volume/probe.comp");
  d.buffer("scene", sizeof(g));
  m.declare(d);
  gpu::Kernel k(ctx,
                std::move(d.buffer("points", points.size() * 16).buffer("sigma", points.size() * 4).push(4)));
  gpu::Bindings b;
  b.set("scene", scene).set("points", pts).set("sigma", sigma);
  m.bind(b);
  const uint32_t n = uint32_t(points.size());
  ctx.submit_and_wait([&](VkCommandBuffer cmd) { k.dispatch_1d(cmd, b, &n, n); });
  return sigma.download_vector<float>();
}

// Two generated clouds whose NanoVDB grids total more than 200 MiB, one of them alone more than 128 MiB
// (lavapipe's maxStorageBufferRange, which bounded every grid together before): each grid is a buffer of
// its own in the ledger, and sigma_t at random points over both clouds, read on the GPU through the
// grids' device addresses, matches NanoVDB's CPU sampler.
// Injected defects caught: both media reading grid 0 (the table's second address replaced by the first):
// the second cloud's points read 0; reads that wrap at 128 MiB (a grid reached only within
// maxStorageBufferRange): 3511 of the 65536 points, those in leaves past the big grid's first 128 MiB.
TEST(Grids, BeyondTheStorageBufferRangeThroughDeviceAddresses) {
  json j = {{"media", {cloud(4.3, -3, 1), cloud(3.2, 3, 2)}}};
  scene::Scene s = make_scene(j);
  volume::Media m(context());
  m.update(s);
  const volume::DeviceMedia& dm = m.host();
  ASSERT_EQ(dm.grids.size(), 2u);
  const uint64_t big = dm.grids[0].nanovdb.size(), small = dm.grids[1].nanovdb.size();
  std::cout << "  grids " << big / double(1 << 20) << " + " << small / double(1 << 20) << " MiB\n";
  ASSERT_GT(big, context().limits().maxStorageBufferRange);
  ASSERT_GT(big + small, 200ull << 20);

  // The ledger lists each grid with its own size, and no buffer holds all of them.
  int listed = 0;
  for (const gpu::LedgerEntry& e : context().ledger().entries()) {
    if (e.name == "nanovdb media[0].grid 'density'" && e.requested == big) ++listed;
    if (e.name == "nanovdb media[1].grid 'density'" && e.requested == small) ++listed;
    EXPECT_LT(e.requested, big + small) << e.name;
  }
  EXPECT_EQ(listed, 2);

  // Points uniform over each medium's world box (their leaves lie all over the grid buffers).
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<glm::vec4> points;
  for (const glsl::GpuMedium& g : dm.media)
    for (int i = 0; i < 32768; ++i) {
      glm::vec3 t{u(rng), u(rng), u(rng)};  // braces: evaluated left to right
      points.emplace_back(glm::mix(glm::vec3(g.world_min), glm::vec3(g.world_max), t), 1.f);
    }
  std::vector<float> gpu = probe(m, points);
  ASSERT_EQ(gpu.size(), points.size());
  vdb::Sampler cpu0(dm.grids[0]), cpu1(dm.grids[1]);
  const vdb::Sampler* cpu[2] = {&cpu0, &cpu1};
  int bad = 0, nonzero = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    // The shader's own world-to-index matrices (float), applied in double.
    double want = 0;
    for (size_t k = 0; k < dm.media.size(); ++k) {
      const glsl::GpuMedium& g = dm.media[k];
      const glm::vec3 x(points[i]);
      if (glm::any(glm::lessThan(x, glm::vec3(g.world_min))) ||
          glm::any(glm::greaterThan(x, glm::vec3(g.world_max))))
        continue;
      const glm::dvec3 p = glm::dvec3(glm::dmat4(g.world_to_index) * glm::dvec4(glm::dvec3(x), 1));
      want += std::max(0.0, double(g.world_min.w) * cpu[k]->trilinear(p));
    }
    nonzero += want > 0;
    if (!(std::abs(gpu[i] - want) <= 1e-4 * want + 1e-5 * 4.5) && bad++ < 5)
      ADD_FAILURE() << "point " << i << ": gpu " << gpu[i] << " cpu " << want;
  }
  EXPECT_EQ(bad, 0);
  EXPECT_GT(nonzero, int(points.size()) / 4);
  EXPECT_EQ(context().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze::test
