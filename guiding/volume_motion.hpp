// Volume motion vectors (docs/guiding.md, virtual points): the previous frame's virtual points projected
// forward into the current camera. Per pixel: the motion of the nearest point that landed there and the
// change of its distance along the ray (the guiding moments shift by it); pixels that receive no point keep
// the G-buffer's surface motion.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "shaders/glsl.hpp"

namespace haze::guiding {

static_assert(sizeof(glsl::MediumMotion) == 23 * 16);

struct VolumeMotionInputs {
  const gpu::Buffer* scene = nullptr;  // GpuScene: cam_* this frame's camera, prev_cam_* the previous one's
  // The previous frame's virtual point depth: distance along the ray through the pixel centre, 0 (or not
  // finite) where there is none; `depth_stride` floats per pixel, the depth at `depth_offset`.
  const gpu::Buffer* prev_depth = nullptr;
  uint32_t depth_stride = 1, depth_offset = 0;
  // This frame's G-buffer layer g_normal (oct normal, motion: the fallback), 16 bytes a pixel.
  const gpu::Buffer* g_normal = nullptr;
  // glsl::MediumMotion per medium that moved, `media_count` of them; nullptr (with count 0): none moved.
  const gpu::Buffer* media = nullptr;
  uint32_t media_count = 0;
  // The velocity grids' address table (shaders/volume/grids.glsl) that MediumMotion::velocity indexes;
  // nullptr: no medium has a velocity (the pass is then compiled without the velocity code).
  const gpu::Buffer* velocity_grids = nullptr;
};

class VolumeMotion {
 public:
  // Needs 64-bit buffer atomics (throws gpu::Error without them). Both frames are width x height; the
  // GpuScene's size is not read.
  VolumeMotion(gpu::Context& ctx, uint32_t width, uint32_t height);
  ~VolumeMotion();

  // Records the passes (timer scope "volume_motion" when a timer is given); ends with a compute barrier.
  void run(VkCommandBuffer cmd, gpu::Timer* timer, const VolumeMotionInputs& in);
  // The baseline without forward projection: each pixel's own virtual point, `in.prev_depth` holding this
  // frame's depth, reprojected into the previous camera (camera motion only; scope "volume_motion_backward").
  // Writes output() as run() does.
  void run_backward(VkCommandBuffer cmd, gpu::Timer* timer, const VolumeMotionInputs& in);

  // vec4 per pixel: xy previous pixel position - current one, z distance of the point from this frame's
  // camera minus d_prev, w 1 where a point landed (else xy the surface motion, z 0, w 0).
  const gpu::Buffer& output() const { return output_; }
  std::vector<glm::vec4> download() const { return output_.download_vector<glm::vec4>(); }
  uint32_t width() const { return width_; }
  uint32_t height() const { return height_; }
  double pipeline_ms() const { return pipeline_ms_; }  // kernels this object compiled and created

 private:
  gpu::Context& ctx_;
  uint32_t width_, height_;
  gpu::Buffer keys_;    // per pixel: (distance bits << 32 | source pixel) of the nearest point, atomicMin
  gpu::Buffer output_;  // vec4 per pixel
  double pipeline_ms_ = 0;
  // Splat (0), resolve (1) and backward (2); no moving media, moving media, moving media with velocity
  // grids (backward: none).
  const gpu::Kernel& kernel(uint32_t step, int moving);
  gpu::Kernel kernels_[3][3];
  // Throws unless `in` is complete; returns 0 (no moving media), 1 (moving media), 2 (with velocity grids).
  int check(const VolumeMotionInputs& in) const;
};

}  // namespace haze::guiding
