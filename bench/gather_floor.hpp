// The floor of the SVGF filter's loads in `haze bench --only svgf`: a kernel that reads what one subsampled
// filter iteration reads per pixel (7 taps of 16 bytes from a storage buffer) and does none of its math
// (shaders/bench/gather.comp). Its time over the copy's is the least one iteration can cost on the device
// through storage buffers; docs/benchmarks.md.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <vector>

#include "gpu/gpu.hpp"

namespace haze::bench {

// One pixel's record: packHalf2x16(r, g), packHalf2x16(b, sigma), depth bits, packSnorm2x16(normal.xy).
using GatherRecord = glm::uvec4;

class GatherFloor {
 public:
  GatherFloor(gpu::Context& ctx, uint32_t width, uint32_t height);
  void upload(const std::vector<GatherRecord>& records);  // width * height of them
  void record(VkCommandBuffer cmd) const;
  std::vector<glm::vec4> download() const;  // the sums, unpacked from half floats

 private:
  uint32_t width_, height_;
  gpu::Buffer records_, sums_;
  gpu::Kernel kernel_;
  gpu::Bindings bindings_;
};

// What the kernel computes, on the CPU in float: per pixel the sum over the centre and the six taps (clamped
// to the image) of (r, g, b, sigma) + (depth, normal.x, normal.y, 0), before the half-float rounding of the
// output.
std::vector<glm::vec4> gather_floor_cpu(const std::vector<GatherRecord>& records, uint32_t width,
                                        uint32_t height);

}  // namespace haze::bench
