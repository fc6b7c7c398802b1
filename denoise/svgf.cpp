#include "denoise/svgf.hpp"

#include <fmt/format.h>

#include <cmath>
#include <glm/gtc/packing.hpp>

namespace haze::denoise {

namespace {

constexpr uint32_t kBlock = 8;

float cos_deg(float deg) {
  return std::cos(glm::radians(deg));
}

glsl::SvgfGpuParams gpu_params(const SvgfParams& p, uint32_t W, uint32_t H, bool remodulate) {
  glsl::SvgfGpuParams g{};
  g.size = glm::uvec4(W, H, (W + kBlock - 1) / kBlock, (H + kBlock - 1) / kBlock);
  g.flags = glm::uvec4(remodulate ? 1 : 0, 0, 0, 0);
  g.accumulate = glm::vec4(p.accumulate, p.max_history, p.adapt_strength, p.adapt_ipr);
  g.percentiles = glm::vec4(p.firefly_low, p.firefly_up, p.adapt_low, p.adapt_up);
  g.firefly = glm::vec4(p.firefly_bias, p.firefly_ipr, p.firefly_max, 0);
  // 180 degrees switches a test off: every cosine passes.
  g.reproject = glm::vec4(p.normal_threshold >= 180.f ? -2.f : cos_deg(p.normal_threshold), p.depth_tolerance,
                          p.border_history, 0);
  g.variance = glm::vec4(p.variance_normal >= 180.f ? -2.f : cos_deg(p.variance_normal), p.variance_depth,
                         p.spatial_bias, p.spatial_falloff);
  g.filter_phi = glm::vec4(p.phi_luminance, p.phi_depth, std::min(cos_deg(p.phi_normal), 0.9999f), 1e-4f);
  g.filter_fade = glm::vec4(p.zbias_normal, p.zbias_depth, 0, 0);
  g.taa = glm::vec4(p.taa_blend, p.taa_clamp == "variance" ? 1.f : 0.f, p.taa_gamma, 0);
  if (p.mode == "classic") {
    // Schied et al. 2017 as in Falcor's SVGF: alpha 0.2, phi_l 4, phi_z 1, normal exponent 128.
    g.accumulate = glm::vec4(0.8f, 32.f, 0, 0);
    g.filter_phi = glm::vec4(4.f, 1.f, 128.f, 1e-4f);
    g.filter_fade = glm::vec4(0);
  }
  return g;
}

}  // namespace

Svgf::Svgf(gpu::Context& ctx, std::string name, const SvgfParams& params, uint32_t width, uint32_t height,
           bool remodulate, const std::string& spv_dir)
    : ctx_(ctx),
      name_(std::move(name)),
      width_(width),
      height_(height),
      remodulate_(remodulate),
      spv_dir_(spv_dir) {
  const uint64_t pixels = uint64_t(width) * height;
  const std::string temps = fmt::format("svgf.{} per-frame temporaries", name_);
  const std::string prev = fmt::format("svgf.{} previous-frame data", name_);
  const uint64_t blocks = uint64_t((width + kBlock - 1) / kBlock) * ((height + kBlock - 1) / kBlock);
  params_buf_ = gpu::Buffer(ctx, fmt::format("svgf.{} parameters", name_), temps, sizeof(glsl::SvgfGpuParams),
                            "SvgfGpuParams");
  percentiles_ = gpu::Buffer(ctx, fmt::format("svgf.{} percentiles", name_), temps, blocks * 16,
                             "4 x f32 per 8x8 block");
  for (int i = 0; i < 2; ++i)
    temp_[i] = gpu::Buffer(ctx, fmt::format("svgf.{} ping-pong {}", name_, i), temps, pixels * 8,
                           "RGBA16F (rgb, sigma | history length); moments as 2 x f32 after accumulation");
  history_ = gpu::Buffer(ctx, fmt::format("svgf.{} history colour", name_), prev, pixels * 8,
                         "RGBA16F (filtered rgb, sigma)");
  moments_ = gpu::Buffer(ctx, fmt::format("svgf.{} history moments", name_), prev,
                         pixels * glsl::SVGF_MOMENTS_STRIDE * 4, "3 x f32 (m1, m2, history length)");
  taa_ = gpu::Buffer(ctx, fmt::format("svgf.{} taa output", name_), prev, pixels * 8, "RGBA16F (rgb, sigma)");
  set_params(params);
}

Svgf::~Svgf() = default;

void Svgf::create_pipelines() {
  const uint32_t classic = params_.mode == "classic" ? 1 : 0;
  const uint32_t subsampled = params_.kernel == "subsampled" ? 1 : 0;
  auto spv = [&](const char* pass) {
    return gpu::variant_spv(spv_dir_, fmt::format("denoise/{}.comp", pass), 0);
  };
  percentiles_pass_ = std::make_unique<gpu::ComputePipeline>(ctx_, spv("percentiles"), 3, 0);
  accumulate_pass_ =
      std::make_unique<gpu::ComputePipeline>(ctx_, spv("accumulate"), 10, 8, std::vector<uint32_t>{classic});
  variance_pass_ =
      std::make_unique<gpu::ComputePipeline>(ctx_, spv("variance"), 6, 0, std::vector<uint32_t>{classic});
  filter_pass_ = std::make_unique<gpu::ComputePipeline>(ctx_, spv("filter"), 4, 4,
                                                        std::vector<uint32_t>{classic, subsampled});
  taa_pass_ = std::make_unique<gpu::ComputePipeline>(ctx_, spv("taa"), 6, 4);
}

void Svgf::set_params(const SvgfParams& params) {
  bool rebuild = !accumulate_pass_ || params.mode != params_.mode || params.kernel != params_.kernel;
  params_ = params;
  const glm::uvec4 layout = gpu_.layout_in;
  gpu_ = gpu_params(params_, width_, height_, remodulate_);
  gpu_.layout_in = layout;
  gpu_dirty_ = true;
  if (rebuild) create_pipelines();
}

double Svgf::pipeline_ms() const {
  double ms = 0;
  for (const auto* p : {&percentiles_pass_, &accumulate_pass_, &variance_pass_, &filter_pass_, &taa_pass_})
    if (*p) ms += (*p)->creation_ms();
  return ms;
}

void Svgf::run(VkCommandBuffer cmd, gpu::Timer* timer, const SvgfInputs& in) {
  if (!in.colour || !in.gbuffer || !in.prev_gbuffer || !in.motion)
    throw gpu::Error(fmt::format("svgf.{}: an input buffer is missing", name_));
  // The parameter buffer changes only with set_params() or the inputs' layout.
  const glm::uvec4 layout(in.colour_stride, in.colour_offset, in.motion_stride, in.motion_offset);
  if (gpu_dirty_ || gpu_.layout_in != layout) {
    gpu_.layout_in = layout;
    vkCmdUpdateBuffer(cmd, params_buf_.handle(), 0, sizeof(gpu_), &gpu_);
    gpu::compute_barrier(cmd);
    gpu_dirty_ = false;
  }

  const uint32_t gx = (width_ + 7) / 8, gy = (height_ + 7) / 8;
  auto scope = [&](const char* pass) {
    if (timer) timer->begin(cmd, fmt::format("svgf.{}.{}", name_, pass));
  };
  auto end = [&] {
    if (timer) timer->end(cmd);
    gpu::compute_barrier(cmd);
  };
  const bool classic = params_.mode == "classic";
  if (!classic) {
    scope("percentiles");
    percentiles_pass_->dispatch(cmd, {&params_buf_, in.colour, &percentiles_}, nullptr, gx, gy);
    end();
  }
  scope("accumulate");
  const uint32_t push[2] = {frame_, has_history_ ? 1u : 0u};
  accumulate_pass_->dispatch(cmd,
                             {&params_buf_, in.colour, in.gbuffer, in.prev_gbuffer, in.motion, &percentiles_,
                              &history_, &moments_, &temp_[0], &temp_[1]},
                             push, gx, gy);
  end();
  scope("variance");
  variance_pass_->dispatch(cmd, {&params_buf_, in.gbuffer, &temp_[0], &temp_[1], &history_, &moments_},
                           nullptr, gx, gy);
  end();
  // history_ now holds (colour, sigma), the first iteration's input. That iteration's output becomes the
  // next frame's history (copied back into history_ once it is no longer read).
  const gpu::Buffer* src = &history_;
  int dst = 0;
  for (uint32_t i = 0; i < uint32_t(params_.iterations); ++i) {
    scope(fmt::format("filter{}", i).c_str());
    filter_pass_->dispatch(cmd, {&params_buf_, in.gbuffer, src, &temp_[dst]}, &i, gx, gy);
    end();
    if (i == 0) {
      gpu::copy_buffer(cmd, temp_[0], history_);
      gpu::compute_barrier(cmd);
    }
    src = &temp_[dst];
    dst ^= 1;
  }
  scope("taa");
  const gpu::Buffer& taa_out = src == &temp_[0] ? temp_[1] : temp_[0];
  const uint32_t taa_push = has_history_ ? 1u : 0u;
  taa_pass_->dispatch(cmd, {&params_buf_, in.gbuffer, in.motion, src, &taa_, &taa_out}, &taa_push, gx, gy);
  end();
  gpu::copy_buffer(cmd, taa_out, taa_);
  gpu::compute_barrier(cmd);
  has_history_ = true;
  ++frame_;
}

SvgfResult Svgf::download() const {
  const size_t pixels = size_t(width_) * height_;
  std::vector<glm::uvec2> out = taa_.download_vector<glm::uvec2>();
  std::vector<float> m = moments_.download_vector<float>();
  SvgfResult r;
  r.colour.resize(pixels);
  r.history.resize(pixels);
  r.variance.resize(pixels);
  for (size_t p = 0; p < pixels; ++p) {
    glm::vec2 rg = glm::unpackHalf2x16(out[p].x), ba = glm::unpackHalf2x16(out[p].y);
    r.colour[p] = glm::vec3(rg, ba.x);
    r.variance[p] = ba.y * ba.y;
    r.history[p] = m[p * glsl::SVGF_MOMENTS_STRIDE + 2];
  }
  return r;
}

}  // namespace haze::denoise
