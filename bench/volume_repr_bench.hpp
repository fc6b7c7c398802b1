// PNanoVDB against a dense float array of the same grid in `haze bench`: the same trilinear density
// lookups (random points, or a fixed-count march along random segments) through the tracker's PNanoVDB code
// and through a plain index-space array of the grid's bounding box (shaders/bench/volume_repr.comp), for a
// dense-ish cloud and a sparse one. Time and memory as ratios nanovdb / dense, measured in one run.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "vdb/vdb.h"

namespace haze::bench {

// One grid on the device in both representations.
struct ReprGrid {
  std::string name;
  gpu::Buffer nanovdb;            // the NanoVDB grid buffer as the tracker uploads it
  gpu::Buffer table;              // its device address: the kernel's grid table, grid 0
  gpu::Buffer dense;              // floats, x fastest, over origin .. origin + dims - 1
  glm::ivec3 origin{0}, dims{0};  // the grid's active index bbox dilated by one voxel (the trilinear support)
  glm::vec3 lo{0}, hi{0};         // index-space domain of the lookup points: [origin, origin + dims - 1)
  uint64_t nanovdb_bytes = 0, dense_bytes = 0;
  uint64_t active_voxels = 0;
};

// Lookup points of invocation `i`: the kernel's rule mirrored on the CPU (for references).
// march = false: n uniform points of [lo, hi); true: n equally spaced points on a random segment.
std::vector<glm::vec3> repr_points(const ReprGrid& g, bool march, uint32_t i, uint32_t n, uint32_t seed);

// The four pipelines (NanoVDB / dense x random lookups / march), created once.
class VolumeReprKernels {
 public:
  explicit VolumeReprKernels(gpu::Context& ctx);
  ~VolumeReprKernels();

  // Uploads `grid` (background 0, checked) as NanoVDB and as a dense array; buffers in category "benchmark".
  ReprGrid upload(const vdb::DeviceGrid& grid, const std::string& name) const;
  // Records one dispatch of `count` invocations, `n` lookups each; out[i] = sum of invocation i's lookups.
  void record(VkCommandBuffer cmd, const ReprGrid& g, bool dense, bool march, uint32_t count, uint32_t n,
              uint32_t seed, const gpu::Buffer& out) const;
  // Submits one dispatch and reads the sums back.
  std::vector<float> run(const ReprGrid& g, bool dense, bool march, uint32_t count, uint32_t n,
                         uint32_t seed) const;

 private:
  gpu::Context& ctx_;
  gpu::Kernel kernels_[2][2];  // [dense][march]
  gpu::Buffer placeholder_;    // for the bindings of medium.glsl the kernel declares but never reads
};

// Largest relative difference between two lists of sums: |a - b| / max(|a|, |b|, floor), with floor =
// 1e-6 * the largest |b| so that values that are zero up to rounding do not count.
double max_relative_difference(const std::vector<float>& a, const std::vector<float>& b);

struct VolumeReprOptions {
  uint32_t invocations = 1u << 16;
  uint32_t lookups = 16;      // random lookups per invocation
  uint32_t march_steps = 64;  // march points per invocation
  int reps = 9;
};

// Both grids, both workloads: {"grids": [{name, nanovdb_bytes, dense_bytes, memory_ratio, lookups: {...},
// march: {...}, max_relative_difference}], ...}. Throws when the two kernels differ by more than 1e-4.
nlohmann::json bench_volume_repr(gpu::Context& ctx, const VolumeReprOptions& o);
void print_volume_repr(const nlohmann::json& j);

}  // namespace haze::bench
