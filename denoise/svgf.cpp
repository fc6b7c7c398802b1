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
                          p.border_history, p.history_test);
  g.variance = glm::vec4(p.variance_normal >= 180.f ? -2.f : cos_deg(p.variance_normal), p.variance_depth,
                         p.spatial_bias, p.spatial_falloff);
  g.filter_phi = glm::vec4(p.phi_luminance, p.phi_depth, std::min(cos_deg(p.phi_normal), 0.9999f), 1e-4f);
  g.filter_fade = glm::vec4(p.zbias_normal, p.zbias_depth, 0, 0);
  g.taa = glm::vec4(p.taa_blend, p.taa_clamp == "variance" ? 1.f : 0.f, p.taa_gamma, 0);
  g.variance_scale =
      glm::vec4(p.filter_sigma == "estimate" ? 1.f : 0.f, std::max(1.f - p.accumulate, 1e-3f), 0, 0);
  if (p.mode == "classic") {
    // Schied et al. 2017 as in Falcor's SVGF: alpha 0.2, phi_l 4, phi_z 1, normal exponent 128.
    g.accumulate = glm::vec4(0.8f, 32.f, 0, 0);
    g.filter_phi = glm::vec4(4.f, 1.f, 128.f, 1e-4f);
    g.filter_fade = glm::vec4(0);
    g.variance_scale = glm::vec4(0);
  }
  return g;
}

}  // namespace

Svgf::Svgf(gpu::Context& ctx, std::string name, const SvgfParams& params, uint32_t width, uint32_t height,
           bool remodulate)
    : ctx_(ctx), name_(std::move(name)), width_(width), height_(height), remodulate_(remodulate) {
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
                         "RGBA16F (rgb, sigma)");
  moments_ = gpu::Buffer(ctx, fmt::format("svgf.{} history moments", name_), prev,
                         pixels * glsl::SVGF_MOMENTS_STRIDE * 4, "3 x f32 (m1, m2, history length)");
  taa_ = gpu::Buffer(ctx, fmt::format("svgf.{} taa output", name_), prev, pixels * 8, "RGBA16F (rgb, sigma)");
  set_params(params);
}

void Svgf::make_geometry_buffers() {
  if (!own_geometry()) {
    geo_ = gpu::Buffer();
    prev_geo_ = gpu::Buffer();
    if (!gpack_.valid())
      gpack_ = gpu::Buffer(ctx_, fmt::format("svgf.{} packed geometry", name_),
                           fmt::format("svgf.{} per-frame temporaries", name_),
                           uint64_t(width_) * height_ * 8, "f32 depth, 2 x snorm16 octahedral normal");
    return;
  }
  gpack_ = gpu::Buffer();
  if (geo_.valid()) return;
  const uint64_t pixels = uint64_t(width_) * height_;
  geo_ = gpu::Buffer(ctx_, fmt::format("svgf.{} geometry", name_),
                     fmt::format("svgf.{} per-frame temporaries", name_), pixels * 8,
                     "f32 virtual point depth, 2 x f16 its gradient");
  prev_geo_ =
      gpu::Buffer(ctx_, fmt::format("svgf.{} previous geometry", name_),
                  fmt::format("svgf.{} previous-frame data", name_), pixels * 4, "f32 virtual point depth");
  geo_.fill_zero();
  prev_geo_.fill_zero();
}

Svgf::~Svgf() = default;

void Svgf::create_kernels() {
  const uint32_t classic = params_.mode == "classic" ? 1 : 0;
  const uint32_t subsampled = params_.kernel == "subsampled" ? 1 : 0;
  const uint32_t pair = !classic && params_.luminance_sigma == "pair" ? 1 : 0;
  const bool epipolar = epipolar_on();
  const uint64_t pixels = uint64_t(width_) * height_;
  const uint64_t blocks = uint64_t(gpu::div_up(width_, kBlock)) * gpu::div_up(height_, kBlock);
  auto decl = [&](const char* pass) {
    gpu::KernelDecl d(fmt::format("denoise/{}.comp", pass));
    d.buffer("params", sizeof(glsl::SvgfGpuParams));
    return d;
  };
  // What the tests and edge stopping compare: the G-buffer layers of this frame (and of the previous one),
  // or the instance's own geometry.
  const bool own = own_geometry();
  auto gbuffer = [&](gpu::KernelDecl& d, const char* prefix) {
    if (own) {
      if (!d.defined("SVGF_OWN_GEOMETRY"))
        d.define("SVGF_OWN_GEOMETRY").buffer("geo", pixels * 8).buffer("prev_geo", pixels * 4);
      return;
    }
    for (const char* layer : {"g_depth", "g_normal", "g_albedo"})
      d.buffer(std::string(prefix) + layer, pixels * 16, 16);
  };
  // The taps' packed geometry (G-buffer geometry only): written by accumulation, read by the spatial passes.
  auto gpack = [&](gpu::KernelDecl& d) {
    if (!own) d.buffer("gpack", pixels * 8);
  };
  const uint64_t half4 = pixels * 8, moments = pixels * glsl::SVGF_MOMENTS_STRIDE * 4;
  auto make = [&](gpu::KernelDecl d) {
    gpu::Kernel k(ctx_, std::move(d));
    pipeline_ms_ += k.setup_ms();
    return k;
  };
  for (uint32_t step = 0; step < 2; ++step) {
    geometry_pass_[step] = gpu::Kernel();
    if (!own) continue;
    gpu::KernelDecl g = decl("geometry");
    gbuffer(g, "");
    g.buffer("depth", pixels * 4);
    geometry_pass_[step] = make(std::move(g.specialize({step})));
  }
  gpu::KernelDecl p = decl("percentiles");
  p.buffer("colour", pixels * 12).buffer("percentiles", blocks * 16);
  percentiles_pass_ = make(std::move(p));
  gpu::KernelDecl a = decl("accumulate");
  a.buffer("colour", pixels * 12);
  gbuffer(a, "");
  gbuffer(a, "prev_");
  gpack(a);
  a.buffer("motion", pixels * 8).buffer("percentiles", blocks * 16).buffer("hist_colour", half4);
  a.buffer("hist_moments", moments).buffer("out_colour", half4).buffer("out_moments", half4);
  if (witness()) a.define("SVGF_HISTORY_WITNESS").buffer("prev_output", half4);
  if (witness() && epipolar) a.define("SVGF_EPIPOLAR");  // the witness along the epipolar line
  accumulate_pass_ = make(std::move(a.push(8).specialize({classic})));
  gpu::KernelDecl v = decl("variance");
  gbuffer(v, "");
  gpack(v);
  v.buffer("acc_colour", half4).buffer("acc_moments", half4).buffer("out_colour", half4);
  v.buffer("hist_moments", moments);
  variance_pass_ = make(std::move(v.specialize({classic})));
  gpu::KernelDecl f = decl("filter");
  gbuffer(f, "");
  gpack(f);
  f.buffer("in_colour", half4).buffer("out_colour", half4).push(4);
  if (epipolar) f.define("SVGF_EPIPOLAR");
  weight_sum_pass_ = gpu::Kernel();
  if (splat()) {
    f.define("SVGF_SPLAT").buffer("weight_sum", pixels * 4);
    gpu::KernelDecl w = f;
    weight_sum_pass_ = make(std::move(w.specialize({classic, subsampled, 1, pair})));
  }
  filter_pass_ = make(std::move(f.specialize({classic, subsampled, 0, pair})));
  taa_pass_ = make(taa_decl());
}

gpu::KernelDecl Svgf::taa_decl() const {
  const uint64_t pixels = uint64_t(width_) * height_, half4 = pixels * 8;
  gpu::KernelDecl t("denoise/taa.comp");
  t.buffer("params", sizeof(glsl::SvgfGpuParams));
  if (own_geometry())
    t.define("SVGF_OWN_GEOMETRY").buffer("geo", pixels * 8).buffer("prev_geo", pixels * 4);
  else
    for (const char* layer : {"g_depth", "g_normal", "g_albedo"}) t.buffer(layer, pixels * 16, 16);
  if (emission_) t.define("SVGF_EMISSION").buffer("emission", pixels * 12);
  t.buffer("motion", pixels * 8).buffer("filtered", half4).buffer("prev_output", half4).buffer("outp", half4);
  return std::move(t.push(4));
}

void Svgf::set_emission(bool emission) {
  if (emission && !remodulate_)
    throw gpu::Error(fmt::format("svgf.{}: an emission input needs a remodulating instance", name_));
  if (emission == emission_) return;
  emission_ = emission;
  if (taa_pass_.valid()) {
    gpu::Kernel k(ctx_, taa_decl());
    pipeline_ms_ += k.setup_ms();
    taa_pass_ = std::move(k);
  }
}

void Svgf::set_params(const SvgfParams& params) {
  if (remodulate_ && params.history_witness == "output")
    throw gpu::Error(
        fmt::format("svgf.{}: history_witness \"output\" needs an instance that does not "
                    "remodulate (its output carries the albedo, its history does not)",
                    name_));
  bool rebuild =
      !accumulate_pass_.valid() || params.mode != params_.mode || params.kernel != params_.kernel ||
      params.geometry != params_.geometry || params.normalization != params_.normalization ||
      params.luminance_sigma != params_.luminance_sigma ||
      params.history_witness != params_.history_witness || (params.epipolar > 0) != (params_.epipolar > 0) ||
      (params.history_test > 0) != (params_.history_test > 0);
  if (params.geometry != params_.geometry) has_history_ = false;  // the history's tests change meaning
  params_ = params;
  make_geometry_buffers();
  if (!splat())
    weight_sum_ = gpu::Buffer();
  else if (!weight_sum_.valid())
    weight_sum_ = gpu::Buffer(ctx_, fmt::format("svgf.{} weight sums", name_),
                              fmt::format("svgf.{} per-frame temporaries", name_),
                              uint64_t(width_) * height_ * 4, "f32 per pixel");
  const glm::uvec4 layout = gpu_.layout_in, flags = gpu_.flags;
  gpu_ = gpu_params(params_, width_, height_, remodulate_);
  gpu_.layout_in = layout;
  gpu_.flags = glm::uvec4(gpu_.flags.x, flags.y, flags.z, flags.w);
  gpu_dirty_ = true;
  if (rebuild) create_kernels();
}

void Svgf::run(VkCommandBuffer cmd, gpu::Timer* timer, const SvgfInputs& in) {
  const bool own = own_geometry();
  if (!in.colour || !in.motion || (own ? !in.depth : (!in.gbuffer || !in.prev_gbuffer)))
    throw gpu::Error(fmt::format("svgf.{}: an input buffer is missing (geometry {} needs {})", name_,
                                 params_.geometry, own ? "a virtual point depth" : "the G-buffers"));
  const uint64_t pixels = uint64_t(width_) * height_;
  auto check = [&](const gpu::Buffer& b, uint32_t stride, uint32_t offset, uint32_t n, const char* what) {
    if (stride < offset + n || b.size() < ((pixels - 1) * stride + offset + n) * 4)
      throw gpu::Error(
          fmt::format("svgf.{}: {} buffer '{}' ({} bytes) does not hold {} pixels of {} floats with "
                      "{} at {}",
                      name_, what, b.name(), b.size(), pixels, stride, n, offset));
  };
  check(*in.colour, in.colour_stride, in.colour_offset, 3, "colour");
  check(*in.motion, in.motion_stride, in.motion_offset, 2, "motion");
  if (bool(in.emission) != emission_)
    throw gpu::Error(fmt::format("svgf.{}: {}", name_,
                                 emission_ ? "set_emission(true) but no emission input"
                                           : "an emission input without set_emission(true)"));
  if (in.emission) check(*in.emission, in.emission_stride, in.emission_offset, 3, "emission");
  if (own) check(*in.depth, in.depth_stride, in.depth_offset, 1, "depth");
  if (epipolar_on() && !in.epipole)
    throw gpu::Error(fmt::format("svgf.{}: epipolar {} needs the light's image (SvgfInputs::epipole)", name_,
                                 params_.epipolar));
  const glm::vec4 epipole =
      epipolar_on() ? glm::vec4(in.epipole->x, in.epipole->y, params_.epipolar, in.epipole->z) : gpu_.epipole;
  // The parameter buffer changes only with set_params(), the inputs' layout or the light's image.
  const glm::uvec4 layout(in.colour_stride, in.colour_offset, in.motion_stride, in.motion_offset);
  const glm::uvec3 emission =
      in.emission ? glm::uvec3(in.emission_stride, in.emission_offset, 1) : glm::uvec3(0);  // w: unused
  const glm::uvec4 geometry = own ? glm::uvec4(in.depth_stride, in.depth_offset, 0, 0) : glm::uvec4(0);
  if (gpu_dirty_ || gpu_.layout_in != layout ||
      glm::uvec3(gpu_.flags.y, gpu_.flags.z, gpu_.flags.w) != emission || gpu_.geometry != geometry ||
      gpu_.epipole != epipole) {
    gpu_.layout_in = layout;
    gpu_.epipole = epipole;
    gpu_.flags = glm::uvec4(gpu_.flags.x, emission);
    gpu_.geometry = geometry;
    vkCmdUpdateBuffer(cmd, params_buf_.handle(), 0, sizeof(gpu_), &gpu_);
    gpu::compute_barrier(cmd);
    gpu_dirty_ = false;
  }
  // What every pass may read: the parameters, the inputs and the G-buffers.
  gpu::Bindings common;
  common.set("params", params_buf_).set("colour", *in.colour).set("motion", *in.motion);
  if (in.emission) common.set("emission", *in.emission);
  if (own) {
    common.set("geo", geo_).set("prev_geo", prev_geo_).set("depth", *in.depth);
  } else {
    in.gbuffer->bind(common);
    in.prev_gbuffer->bind(common);
    common.set("gpack", gpack_);
  }

  const uint32_t gx = (width_ + 7) / 8, gy = (height_ + 7) / 8;
  auto scope = [&](const char* pass) {
    if (timer) timer->begin(cmd, fmt::format("svgf.{}.{}", name_, pass));
  };
  auto end = [&] {
    if (timer) timer->end(cmd);
    gpu::compute_barrier(cmd);
  };
  if (own) {
    scope("geometry");
    geometry_pass_[0].dispatch(cmd, common, nullptr, gx, gy);
    end();
  }
  const bool classic = params_.mode == "classic";
  if (!classic) {
    scope("percentiles");
    gpu::Bindings b = common;
    b.set("percentiles", percentiles_);
    percentiles_pass_.dispatch(cmd, b, nullptr, gx, gy);
    end();
  }
  scope("accumulate");
  const uint32_t push[2] = {frame_, has_history_ ? 1u : 0u};
  {
    gpu::Bindings b = common;
    b.set("percentiles", percentiles_).set("hist_colour", history_).set("hist_moments", moments_);
    b.set("out_colour", temp_[0]).set("out_moments", temp_[1]);
    if (witness()) b.set("prev_output", taa_);
    accumulate_pass_.dispatch(cmd, b, push, gx, gy);
  }
  end();
  if (own) {
    // The gradient of the depth accumulation just wrote.
    scope("geometry_gradient");
    geometry_pass_[1].dispatch(cmd, common, nullptr, gx, gy);
    end();
  }
  scope("variance");
  {
    gpu::Bindings b = common;
    b.set("acc_colour", temp_[0]).set("acc_moments", temp_[1]).set("out_colour", history_);
    b.set("hist_moments", moments_);
    variance_pass_.dispatch(cmd, b, nullptr, gx, gpu::div_up(height_, 8 * glsl::SVGF_VARIANCE_ROWS));
  }
  end();
  // history_ now holds (colour, sigma), the first iteration's input and the next frame's history. With
  // filtered feedback the first iteration's output replaces it (copied back once it is no longer read).
  const bool feed_filtered = classic || params_.feedback == "filtered";
  const gpu::Buffer* src = &history_;
  int dst = 0;
  for (uint32_t i = 0; i < uint32_t(params_.iterations); ++i) {
    scope(fmt::format("filter{}", i).c_str());
    gpu::Bindings b = common;
    b.set("in_colour", *src).set("out_colour", temp_[dst]);
    if (weight_sum_pass_.valid()) {
      b.set("weight_sum", weight_sum_);
      weight_sum_pass_.dispatch(cmd, b, &i, gx, gy);
      gpu::compute_barrier(cmd);
    }
    filter_pass_.dispatch(cmd, b, &i, gx, gy);
    end();
    if (i == 0 && feed_filtered) {
      gpu::copy_buffer(cmd, temp_[0], history_);
      gpu::compute_barrier(cmd);
    }
    src = &temp_[dst];
    dst ^= 1;
  }
  scope("taa");
  const gpu::Buffer& taa_out = src == &temp_[0] ? temp_[1] : temp_[0];
  const uint32_t taa_push = has_history_ ? 1u : 0u;
  {
    gpu::Bindings b = common;
    b.set("filtered", *src).set("prev_output", taa_).set("outp", taa_out);
    taa_pass_.dispatch(cmd, b, &taa_push, gx, gy);
  }
  end();
  gpu::copy_buffer(cmd, taa_out, taa_);
  gpu::compute_barrier(cmd);
  has_history_ = true;
  ++frame_;
}

SvgfResult Svgf::download() const {
  return decode(size_t(width_) * height_, taa_.download_vector<glm::uvec2>(),
                moments_.download_vector<float>());
}

SvgfResult Svgf::decode(size_t pixels, const std::vector<glm::uvec2>& out, const std::vector<float>& m) {
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
