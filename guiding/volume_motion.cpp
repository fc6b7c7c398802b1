#include "guiding/volume_motion.hpp"

#include <fmt/format.h>

#include "volume/glsl.hpp"

namespace haze::guiding {

namespace {

// volume_motion.comp's push constants.
struct Push {
  glm::uvec2 size;
  uint32_t depth_stride, depth_offset, media_count;
};

void require(const gpu::Buffer* b, uint64_t bytes, const char* what) {
  if (!b || !b->valid()) throw gpu::Error(fmt::format("volume motion: the {} buffer is missing", what));
  if (b->size() < bytes)
    throw gpu::Error(fmt::format("volume motion: the {} buffer '{}' holds {} bytes, needs {}", what,
                                 b->name(), b->size(), bytes));
}

}  // namespace

VolumeMotion::VolumeMotion(gpu::Context& ctx, uint32_t width, uint32_t height, const std::string& spv_dir)
    : width_(width), height_(height) {
  if (!ctx.features().int64 || !ctx.features().buffer_int64_atomics)
    throw gpu::Error("volume motion needs shaderInt64 and shaderBufferInt64Atomics, which this device lacks");
  if (width == 0 || height == 0) throw gpu::Error("volume motion: empty image");
  const uint64_t pixels = uint64_t(width) * height;
  keys_ = gpu::Buffer(ctx, "volume motion keys", "per-frame temporaries", pixels * 8,
                      "u64 per pixel (distance bits << 32 | source pixel)");
  output_ = gpu::Buffer(ctx, "volume motion", "volume motion", pixels * 16,
                        "4 x f32 per pixel (motion xy, distance change, landed)");
  const std::string spv = gpu::variant_spv(spv_dir, "guiding/volume_motion.comp", 0);
  splat_ = std::make_unique<gpu::ComputePipeline>(ctx, spv, 6, sizeof(Push), std::vector<uint32_t>{0});
  resolve_ = std::make_unique<gpu::ComputePipeline>(ctx, spv, 6, sizeof(Push), std::vector<uint32_t>{1});
}

VolumeMotion::~VolumeMotion() = default;

double VolumeMotion::pipeline_ms() const {
  return splat_->creation_ms() + resolve_->creation_ms();
}

void VolumeMotion::run(VkCommandBuffer cmd, gpu::Timer* timer, const VolumeMotionInputs& in) {
  const uint64_t pixels = uint64_t(width_) * height_;
  require(in.scene, sizeof(::haze::glsl::GpuScene), "scene");
  require(in.prev_depth, ((pixels - 1) * in.depth_stride + in.depth_offset + 1) * 4, "previous depth");
  require(in.gbuffer, pixels * ::haze::glsl::G_STRIDE * 4, "g-buffer");
  if (in.media_count > 0) require(in.media, in.media_count * sizeof(glsl::MediumMotion), "media motion");
  // With no moving media the shader never reads binding 3, so any valid buffer can stand there.
  const gpu::Buffer* media = in.media_count > 0 ? in.media : in.scene;
  const Push push{glm::uvec2(width_, height_), in.depth_stride, in.depth_offset, in.media_count};
  const uint32_t gx = gpu::div_up(width_, 8), gy = gpu::div_up(height_, 8);

  if (timer) timer->begin(cmd, "volume_motion");
  keys_.fill(cmd, 0xffffffffu);  // no point landed
  gpu::compute_barrier(cmd);
  splat_->dispatch(cmd, {in.scene, in.prev_depth, in.gbuffer, media, &keys_, &output_}, &push, gx, gy);
  gpu::compute_barrier(cmd);
  resolve_->dispatch(cmd, {in.scene, in.prev_depth, in.gbuffer, media, &keys_, &output_}, &push, gx, gy);
  if (timer) timer->end(cmd);
  gpu::compute_barrier(cmd);
}

}  // namespace haze::guiding
