// One percentile-adaptive SVGF instance (docs/denoising.md): the passes percentiles, accumulate, variance,
// N filter iterations and TAA, their buffers and kernels. It knows images and G-buffers only; the
// renderer runs a surface instance on the demodulated surface signal and a volume instance on the volume
// signal.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "denoise/params.hpp"
#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "gpu/pixel_layers.hpp"

namespace haze::denoise {

// shaders/denoise/svgf_layout.glsl compiled as C++: the parameter block the passes read.
namespace glsl {
using namespace glm;
using uint = glm::uint;
#include "shaders/denoise/svgf_layout.glsl"
static_assert(sizeof(SvgfGpuParams) == 14 * 16);
}  // namespace glsl

// What an instance reads. Colour and motion are `stride` floats per pixel with the rgb (xy) at `offset`;
// the G-buffers are the layers of shaders/common/gbuffer.glsl: this frame's named g_depth, g_normal and
// g_albedo, the previous frame's prev_g_depth, prev_g_normal and prev_g_albedo.
struct SvgfInputs {
  const gpu::Buffer* colour = nullptr;
  uint32_t colour_stride = 3, colour_offset = 0;
  const gpu::PixelLayers* gbuffer = nullptr;
  const gpu::PixelLayers* prev_gbuffer = nullptr;
  const gpu::Buffer* motion = nullptr;
  uint32_t motion_stride = 2, motion_offset = 0;
  // Optional, remodulating instances only: the emission kept out of the demodulated colour (rgb); it
  // bypasses the filters and is added after remodulation.
  const gpu::Buffer* emission = nullptr;
  uint32_t emission_stride = 3, emission_offset = 0;
  // Instances with geometry "virtual_points" only: the signal's virtual point depth per pixel (distance along
  // the pixel-centre ray; <= 0 or not finite: none), `depth_stride` floats per pixel, at `depth_offset`.
  // They read no G-buffer.
  const gpu::Buffer* depth = nullptr;
  uint32_t depth_stride = 1, depth_offset = 0;
  // Instances with epipolar > 0 only: this frame's image of the one light that casts the shafts, in
  // homogeneous pixel coordinates (x, y, w; w = 0 for a direction parallel to the image plane).
  std::optional<glm::vec3> epipole = std::nullopt;
};

// Downloaded output: remodulated colour after TAA, the history length, and the variance of the filtered
// (demodulated) luminance.
struct SvgfResult {
  std::vector<glm::vec3> colour;
  std::vector<float> history, variance;
};

class Svgf {
 public:
  // `name` ("surface", "volume") prefixes the passes' timer names and the ledger categories. `remodulate`:
  // multiply by the G-buffer albedo at the end (the input was divided by it).
  Svgf(gpu::Context& ctx, std::string name, const SvgfParams& params, uint32_t width, uint32_t height,
       bool remodulate);
  ~Svgf();

  void set_params(const SvgfParams& params);
  // Whether run() gets an emission input (a remodulating instance in a scene with emissive surfaces): the
  // TAA pass that adds it back is a permutation of its own, and without it has no emission binding.
  void set_emission(bool emission);
  bool emission() const { return emission_; }
  // The next frame starts without history (a cut, a new sequence).
  void reset() { has_history_ = false; }
  // Records the passes of one frame (timer scopes "svgf.<name>.<pass>" when a timer is given).
  void run(VkCommandBuffer cmd, gpu::Timer* timer, const SvgfInputs& in);
  SvgfResult download() const;
  // download() of copies of output() and moments() (a frame's readback).
  static SvgfResult decode(size_t pixels, const std::vector<glm::uvec2>& output,
                           const std::vector<float>& moments);

  const gpu::Buffer& output() const { return taa_; }       // half rgb + sigma per pixel (see taa.comp)
  const gpu::Buffer& moments() const { return moments_; }  // SVGF_MOMENTS_STRIDE floats per pixel
  // Adaptive mode: per 8x8 block (row-major) the firefly low, up and adaptivity low, up percentiles of the
  // last run()'s input (percentiles.comp).
  const gpu::Buffer& percentiles() const { return percentiles_; }
  // Geometry "virtual_points" only: the virtual point depth accumulated over the history (float bits, then
  // its gradient: 2 words per pixel, the depth first), as the last run() left it; else nullptr.
  const gpu::Buffer* geometry_depth() const { return geo_.valid() ? &geo_ : nullptr; }
  uint32_t width() const { return width_; }
  uint32_t height() const { return height_; }
  const std::string& name() const { return name_; }
  // The filter's epipolar term runs (epipolar > 0, adaptive mode): run() then needs SvgfInputs::epipole.
  bool epipolar_on() const { return params_.epipolar > 0 && params_.mode != "classic"; }
  double pipeline_ms() const { return pipeline_ms_; }  // kernels this instance compiled and created

 private:
  gpu::Context& ctx_;
  std::string name_;
  SvgfParams params_;
  uint32_t width_, height_;
  bool remodulate_;
  bool has_history_ = false;
  bool emission_ = false;
  glsl::SvgfGpuParams gpu_{};  // params_ as the shaders read them
  bool gpu_dirty_ = true;      // gpu_ not yet in params_buf_
  uint32_t frame_ = 0;
  // Temporaries: percentiles and two half-float ping-pong buffers. Previous-frame data: the history colour,
  // the moments (m1, m2, n) and the TAA output. With geometry "virtual_points": this frame's depth and
  // gradient (geo) and the last frame's depth (prev_geo).
  gpu::Buffer params_buf_, percentiles_, temp_[2], history_, moments_, taa_, geo_, prev_geo_;
  gpu::Buffer weight_sum_;  // normalization "splat": per pixel the sum of the weights it gives away
  gpu::Buffer gpack_;       // G-buffer geometry: the taps' depth and normal, one word (svgf_common.glsl)
  gpu::Kernel geometry_pass_[2], percentiles_pass_, accumulate_pass_, variance_pass_, filter_pass_, taa_pass_;
  gpu::Kernel weight_sum_pass_;
  bool splat() const { return params_.normalization == "splat" && params_.mode != "classic"; }
  bool own_geometry() const { return params_.geometry == "virtual_points"; }
  // The history test judges the previous frame's output instead of the history (history_witness "output").
  bool witness() const {
    return params_.mode != "classic" && params_.history_test > 0 && params_.history_witness == "output";
  }
  void make_geometry_buffers();
  double pipeline_ms_ = 0;
  void create_kernels();
  gpu::KernelDecl taa_decl() const;
};

}  // namespace haze::denoise
