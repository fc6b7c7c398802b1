// The kernels of `haze bench volume_repr` (shaders/bench/volume_repr.comp) on lavapipe with the validation
// layer on: the PNanoVDB kernel and the dense-array kernel both agree with NanoVDB's CPU sampler
// (nanovdb::SampleFromVoxels, order 1, through vdb::Sampler) on small grids, for random lookups and for the
// march; and `--only` names are checked.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <glm/gtc/packing.hpp>
#include <random>

#include "bench/bench.hpp"
#include "bench/gather_floor.hpp"
#include "bench/volume_repr_bench.hpp"
#include "render/renderer.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

bench::VolumeReprKernels& kernels() {
  static bench::VolumeReprKernels k(context());
  return k;
}

vdb::ProceduralSpec small_cloud(double falloff, uint32_t seed) {
  vdb::ProceduralSpec s;
  s.kind = "cloud";
  s.voxel_size = 0.15;
  s.center = {0.3, -0.2, 0.1};  // negative and positive indices
  s.size = glm::dvec3(2.4);
  s.density = 4;
  s.falloff = falloff;
  s.frequency = 1.5;
  s.seed = seed;
  return s;
}

// Each kernel's per-invocation sums against the CPU sampler at the same points: |gpu - cpu| <= 1e-4 |cpu| +
// 1e-5 max|value| (float weights on the GPU, double on the CPU).
void check_against_cpu(const vdb::ProceduralSpec& spec, bool march, uint32_t n) {
  vdb::DeviceGrid dg = vdb::make_procedural(spec);
  bench::ReprGrid g = kernels().upload(dg, "test");
  vdb::Sampler cpu(dg);
  const uint32_t count = 2048, seed = 5;
  std::vector<double> ref(count);
  size_t nonzero = 0, zero = 0;
  for (uint32_t i = 0; i < count; ++i) {
    for (const glm::vec3& p : bench::repr_points(g, march, i, n, seed)) {
      const double v = cpu.trilinear(glm::dvec3(p));
      ref[i] += v;
      (v > 0 ? nonzero : zero)++;
    }
  }
  // The points cover both the medium and the empty space around it.
  EXPECT_GT(nonzero, size_t(count) * n / 10);
  EXPECT_GT(zero, size_t(count) * n / 100);
  const double tol_abs = 1e-5 * std::max(std::abs(dg.value_max), std::abs(dg.value_min)) * n;
  std::vector<float> sums[2];
  for (int dense = 0; dense < 2; ++dense) {
    sums[dense] = kernels().run(g, dense != 0, march, count, n, seed);
    ASSERT_EQ(sums[dense].size(), count);
    int bad = 0;
    for (uint32_t i = 0; i < count; ++i) {
      const double d = std::abs(sums[dense][i] - ref[i]);
      if (!(d <= 1e-4 * std::abs(ref[i]) + tol_abs) && bad++ < 5)
        ADD_FAILURE() << (dense ? "dense" : "nanovdb") << (march ? " march" : " lookups") << " invocation "
                      << i << ": gpu " << sums[dense][i] << " cpu " << ref[i];
    }
    EXPECT_EQ(bad, 0) << (dense ? "dense" : "nanovdb");
  }
  EXPECT_LE(bench::max_relative_difference(sums[0], sums[1]), 1e-4);
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(BenchKernels, RandomLookupsMatchCpuSampler) {
  check_against_cpu(small_cloud(0.6, 3), false, 1);
}

TEST(BenchKernels, MarchMatchesCpuSampler) {
  check_against_cpu(small_cloud(0.6, 3), true, 8);
}

TEST(BenchKernels, SparseGridMatchesCpuSampler) {
  check_against_cpu(small_cloud(1.0, 11), false, 4);
}

TEST(BenchKernels, DenseCoversTheTrilinearSupport) {
  vdb::DeviceGrid dg = vdb::make_procedural(small_cloud(0.6, 3));
  bench::ReprGrid g = kernels().upload(dg, "test");
  EXPECT_EQ(g.origin, dg.index_min - 1);
  EXPECT_EQ(g.dims, dg.index_max - dg.index_min + 3);
  EXPECT_EQ(g.dense_bytes, uint64_t(g.dims.x) * g.dims.y * g.dims.z * 4);
  EXPECT_EQ(g.nanovdb_bytes, dg.nanovdb.size());
  // Both buffers are in the ledger under "benchmark".
  EXPECT_GE(context().ledger().per_category().at("benchmark"), g.dense_bytes + g.nanovdb_bytes);
}

TEST(BenchKernels, MaxRelativeDifference) {
  EXPECT_EQ(bench::max_relative_difference({1.f, 0.f, 2.f}, {1.f, 0.f, 2.f}), 0.0);
  EXPECT_NEAR(bench::max_relative_difference({1.f, 2.f}, {1.f, 2.002f}), 1e-3, 1e-5);
  EXPECT_TRUE(std::isinf(bench::max_relative_difference({NAN}, {1.f})));
  EXPECT_TRUE(std::isinf(bench::max_relative_difference({1.f}, {1.f, 2.f})));
}

// The SVGF gather floor (shaders/bench/gather.comp) sums the same 7 clamped taps as its CPU twin: per pixel
// and channel within the output's half-float rounding (2^-11 relative). A kernel that dropped a tap, read the
// wrong record or skipped the border's clamp would be off by a whole record's value.
TEST(BenchKernels, GatherFloorSumsTheFilterTaps) {
  const uint32_t W = 37, H = 21;  // not multiples of the 8x8 group
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.f, 4.f), n(-1.f, 1.f);
  std::vector<bench::GatherRecord> rec(size_t(W) * H);
  for (auto& r : rec)
    r = {glm::packHalf2x16({u(rng), u(rng)}), glm::packHalf2x16({u(rng), u(rng)}),
         glm::floatBitsToUint(u(rng)), glm::packSnorm2x16({n(rng), n(rng)})};
  bench::GatherFloor g(context(), W, H);
  g.upload(rec);
  context().submit_and_wait([&](VkCommandBuffer cmd) { g.record(cmd); });
  const std::vector<glm::vec4> gpu = g.download(), cpu = bench::gather_floor_cpu(rec, W, H);
  ASSERT_EQ(gpu.size(), cpu.size());
  for (size_t i = 0; i < cpu.size(); ++i)
    for (int c = 0; c < 4; ++c)
      ASSERT_NEAR(gpu[i][c], cpu[i][c], std::abs(cpu[i][c]) * std::ldexp(1.f, -11) + 1e-6f)
          << "pixel " << i % W << "," << i / W << " channel " << c;
}

TEST(BenchKernels, OnlyNamesParts) {
  // Everything but the efficiency comparison and the shaft sequence (minutes), which run when named.
  std::vector<std::string> all = bench::part_names();
  for (const char* named_only : {"efficiency", "shafts"})
    all.erase(std::find(all.begin(), all.end(), named_only));
  EXPECT_EQ(bench::parse_only(""), all);
  EXPECT_EQ(bench::parse_only("efficiency"), std::vector<std::string>{"efficiency"});
  EXPECT_EQ(bench::parse_only("shafts"), std::vector<std::string>{"shafts"});
  EXPECT_EQ(bench::parse_only("volume_repr, first_frame"),
            (std::vector<std::string>{"first_frame", "volume_repr"}));
  try {
    bench::parse_only("svgf,bogus");
    ADD_FAILURE() << "no error for an unknown part";
  } catch (const std::exception& e) {
    std::string m = e.what();
    EXPECT_NE(m.find("'bogus'"), std::string::npos) << m;
    for (const auto& n : bench::part_names()) EXPECT_NE(m.find(n), std::string::npos) << m;
    EXPECT_EQ(m.find('\n'), std::string::npos) << m;
  }
}

}  // namespace
}  // namespace haze::test
