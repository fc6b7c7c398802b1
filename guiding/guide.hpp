// The distance-guiding state on the device (docs/guiding.md): K states {W, N, m1, m2} per vertex of a
// screen-space grid, read and written by the trace kernel, carried to the next frame through the volume
// motion vectors by the reproject pass. Without guiding nothing is allocated and no kernel has guide code.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <vector>

#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "guiding/params.hpp"
#include "shaders/glsl.hpp"

namespace haze::guiding {

// Vertices across and down the grid of a width x height image (GpuScene::guide_grid.xy).
glm::uvec2 grid_size(const GuidingParams& p, uint32_t width, uint32_t height);

class Guide : public gpu::DeviceData {
 public:
  explicit Guide(gpu::Context& ctx) : ctx_(ctx) {}

  // `active`: guiding is enabled and the scene has a medium and a light (else the state is dropped). The
  // states survive a call with an unchanged grid; `reset` empties them (a new, independent run).
  void update(const GuidingParams& p, uint32_t width, uint32_t height, bool active, bool reset);
  bool active() const { return states_.valid(); }

  // HAZE_GUIDING and the binding "guide_states".
  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
  void fill(glsl::GpuScene& g) const;  // guide, guide_grid, guide_learn

  // Before the frame's first sample: an empty grid without temporal reuse, else (when a previous frame
  // exists) each vertex takes the states of the previous frame's vertex its virtual point came from.
  // `scene` is the frame's scene block, `motion` the volume motion (vec4 per pixel).
  void start_frame(VkCommandBuffer cmd, gpu::Timer* timer, const gpu::Buffer& scene,
                   const gpu::Buffer* motion, bool has_previous);
  std::vector<glm::vec4> download() const;

 private:
  gpu::Context& ctx_;
  GuidingParams params_;
  glm::uvec2 grid_{0};
  uint32_t width_ = 0, height_ = 0;
  gpu::Buffer states_, prev_states_;
  gpu::Kernel reproject_;
};

}  // namespace haze::guiding
