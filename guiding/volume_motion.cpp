#include "guiding/volume_motion.hpp"

#include <fmt/format.h>

namespace haze::guiding {

namespace {

// volume_motion.comp's push constants.
struct Push {
  glm::uvec2 size;
  uint32_t depth_stride, depth_offset, media_count;
};

}  // namespace

VolumeMotion::VolumeMotion(gpu::Context& ctx, uint32_t width, uint32_t height)
    : ctx_(ctx), width_(width), height_(height) {
  if (!ctx.features().int64 || !ctx.features().buffer_int64_atomics)
    throw gpu::Error("volume motion needs shaderInt64 and shaderBufferInt64Atomics, which this device lacks");
  if (width == 0 || height == 0) throw gpu::Error("volume motion: empty image");
  const uint64_t pixels = uint64_t(width) * height;
  keys_ = gpu::Buffer(ctx, "volume motion keys", "per-frame temporaries", pixels * 8,
                      "u64 per pixel (distance bits << 32 | source pixel)");
  output_ = gpu::Buffer(ctx, "volume motion", "volume motion", pixels * 16,
                        "4 x f32 per pixel (motion xy, distance change, landed)");
  // Both kernels of the usual case (no moving media) up front, so that the first frame does not pay.
  kernel(0, 0);
  kernel(1, 0);
}

VolumeMotion::~VolumeMotion() = default;

const gpu::Kernel& VolumeMotion::kernel(uint32_t step, int moving) {
  gpu::Kernel& k = kernels_[step][moving];
  if (!k.valid()) {
    const uint64_t pixels = uint64_t(width_) * height_;
    gpu::KernelDecl d("guiding/volume_motion.comp");
    if (moving == 2) d.define("HAZE_VELOCITY");
    d.buffer("scene", sizeof(glsl::GpuScene))
        .buffer("prev_depth", pixels * 4)
        .buffer("g_normal", pixels * 16, 16);
    if (moving) d.buffer("media_motion", sizeof(glsl::MediumMotion), sizeof(glsl::MediumMotion));
    if (moving == 2) d.buffer("grids", 8, 8);
    d.buffer("keys", pixels * 8).buffer("motion", pixels * 16).push(sizeof(Push)).specialize({step});
    k = gpu::Kernel(ctx_, std::move(d));
    pipeline_ms_ += k.setup_ms();
  }
  return k;
}

int VolumeMotion::check(const VolumeMotionInputs& in) const {
  if (!in.scene || !in.prev_depth || !in.g_normal)
    throw gpu::Error("volume motion: the scene, previous depth or g-buffer buffer is missing");
  const uint64_t pixels = uint64_t(width_) * height_;
  if (in.depth_stride == 0 || in.depth_offset >= in.depth_stride ||
      in.prev_depth->size() < ((pixels - 1) * in.depth_stride + in.depth_offset + 1) * 4)
    throw gpu::Error(
        fmt::format("volume motion: previous depth buffer '{}' ({} bytes) does not hold {} pixels of "
                    "stride {} with the depth at {}",
                    in.prev_depth->name(), in.prev_depth->size(), pixels, in.depth_stride, in.depth_offset));
  const int moving = in.media_count == 0 ? 0 : in.velocity_grids ? 2 : 1;
  if (moving && (!in.media || in.media->size() < in.media_count * sizeof(glsl::MediumMotion)))
    throw gpu::Error(
        fmt::format("volume motion: {} moving media but their buffer holds fewer", in.media_count));
  return moving;
}

void VolumeMotion::run(VkCommandBuffer cmd, gpu::Timer* timer, const VolumeMotionInputs& in) {
  const int moving = check(in);
  gpu::Bindings b;
  b.set("scene", *in.scene).set("prev_depth", *in.prev_depth).set("g_normal", *in.g_normal);
  b.set("keys", keys_).set("motion", output_);
  if (moving) b.set("media_motion", *in.media);
  if (moving == 2) b.set("grids", *in.velocity_grids);
  const Push push{glm::uvec2(width_, height_), in.depth_stride, in.depth_offset, in.media_count};
  const uint32_t gx = gpu::div_up(width_, 8), gy = gpu::div_up(height_, 8);

  const gpu::Kernel& splat = kernel(0, moving);
  const gpu::Kernel& resolve = kernel(1, moving);
  if (timer) timer->begin(cmd, "volume_motion");
  keys_.fill(cmd, 0xffffffffu);  // no point landed
  gpu::compute_barrier(cmd);
  splat.dispatch(cmd, b, &push, gx, gy);
  gpu::compute_barrier(cmd);
  resolve.dispatch(cmd, b, &push, gx, gy);
  if (timer) timer->end(cmd);
  gpu::compute_barrier(cmd);
}

void VolumeMotion::run_backward(VkCommandBuffer cmd, gpu::Timer* timer, const VolumeMotionInputs& in) {
  check(in);
  gpu::Bindings b;
  b.set("scene", *in.scene).set("prev_depth", *in.prev_depth).set("g_normal", *in.g_normal);
  b.set("keys", keys_).set("motion", output_);
  const Push push{glm::uvec2(width_, height_), in.depth_stride, in.depth_offset, 0};
  if (timer) timer->begin(cmd, "volume_motion_backward");
  kernel(2, 0).dispatch(cmd, b, &push, gpu::div_up(width_, 8), gpu::div_up(height_, 8));
  if (timer) timer->end(cmd);
  gpu::compute_barrier(cmd);
}

}  // namespace haze::guiding
