#include "view/layers.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace haze::view {
namespace {

// shaders/view/display.comp: modes and push constants.
enum Mode : uint32_t { kColour = 0, kColourHalf = 1, kScalar = 2, kMotion = 3, kNormal = 4, kGuide = 5 };
struct DisplayPush {
  uint32_t pixels, width, mode, stride;
  uint32_t offset;
  float scale, exposure_scale;
  uint32_t tonemap;
  glm::uvec4 guide;
};
static_assert(sizeof(DisplayPush) == 48);

// Where a resolved (OUT_*) or G-buffer (G_*) float lives: its layer and the component in it.
const gpu::Buffer& layer_of(const gpu::PixelLayers& l, uint32_t offset) {
  return l[offset / 4];
}

}  // namespace

const std::vector<LayerInfo>& layers() {
  static const std::vector<LayerInfo> all = {
      {"final", "what the PNG preview shows: the denoised composite where a denoiser runs, else the mean"},
      {"noisy", "the mean of the samples so far (R, G, B): surface term + volume term"},
      {"surface", "the surface term T(0, t_s) L(t_s)"},
      {"volume", "the volume term: in-scattered and emitted light along the camera ray"},
      {"denoised", "the composite of the denoisers' outputs (each signal's mean where its instance is off)"},
      {"surface_denoised", "the surface SVGF instance's output"},
      {"surface_history", "its history length, frames (white: denoise.surface.max_history)"},
      {"volume_denoised", "the volume SVGF instance's output"},
      {"volume_history", "its history length, frames (white: denoise.volume.max_history)"},
      {"motion", "surface motion vectors, pixels (red x, green y; 0.5 is still, 16 pixels saturate)"},
      {"volume_motion", "the virtual points' motion vectors, pixels (as motion)"},
      {"virtual_point_depth",
       "where the volume contribution concentrates along the ray (white: the scene's size)"},
      {"guide_mean", "the guide's contribution-weighted mean distance at the nearest grid vertex"},
      {"variance", "per-pixel variance of one sample of the final radiance, through the tone curve"},
      {"depth", "distance to the first surface (white: the scene's size)"},
      {"normal", "surface normal, 0.5 + 0.5 n"},
      {"albedo", "surface albedo"},
  };
  return all;
}

std::vector<std::string> layer_names() {
  std::vector<std::string> n;
  for (const auto& l : layers()) n.push_back(l.name);
  return n;
}

LayerDisplay::LayerDisplay(gpu::Context& ctx) : ctx_(ctx) {
  kernel_ = gpu::Kernel(
      ctx, gpu::KernelDecl("view/display.comp").buffer("src").buffer("display").push(sizeof(DisplayPush)));
}

bool LayerDisplay::available(const render::Renderer& r, const std::string& layer) {
  if (layer == "surface_denoised" || layer == "surface_history") return r.surface_denoiser() != nullptr;
  if (layer == "volume_denoised" || layer == "volume_history") return r.volume_denoiser() != nullptr;
  if (layer == "denoised") return r.surface_denoiser() || r.volume_denoiser();
  if (layer == "volume_motion") return r.volume_motion() != nullptr;
  if (layer == "guide_mean") return r.guide().active();
  return std::find_if(layers().begin(), layers().end(),
                      [&](const LayerInfo& l) { return l.name == layer; }) != layers().end();
}

void LayerDisplay::record(VkCommandBuffer cmd, gpu::Timer* timer, const render::Renderer& r,
                          const std::string& layer, float extent, gpu::Buffer& display) {
  const scene::Scene& s = r.scene();
  const uint32_t pixels = uint32_t(s.render.width) * uint32_t(s.render.height);
  if (display.size() < uint64_t(pixels) * 4)
    throw gpu::Error(fmt::format("viewer: display buffer of {} bytes for {} pixels", display.size(), pixels));
  if (!available(r, layer))
    throw gpu::Error(fmt::format("viewer: layer '{}' is not available in this scene", layer));
  if (timer) timer->begin(cmd, "view.display");
  gpu::compute_barrier(cmd);
  if (layer == "final") {
    gpu::copy_buffer(cmd, r.preview(), display, uint64_t(pixels) * 4);
  } else {
    const render::TonemapPush tp = render::tonemap_push(s.render, pixels);
    DisplayPush push{pixels, uint32_t(s.render.width), kColour, 4, 0, 1.f, tp.exposure_scale, tp.tonemap, {}};
    const gpu::Buffer* src = nullptr;
    const auto& out = r.resolved();
    const auto& g = r.gbuffer();
    auto float_layer = [&](const gpu::PixelLayers& l, uint32_t offset, Mode mode, float scale = 1.f) {
      src = &layer_of(l, offset);
      push.offset = offset % 4;
      push.mode = mode;
      push.scale = scale;
    };
    auto history = [&](const denoise::Svgf& d, float max_history) {
      src = &d.moments();
      push.mode = kScalar;
      push.stride = denoise::glsl::SVGF_MOMENTS_STRIDE;
      push.offset = 2;
      push.scale = 1.f / max_history;
    };
    const float distance_scale = 1.f / std::max(extent, 1e-6f);
    if (layer == "noisy") {
      float_layer(out, glsl::OUT_L, kColour);
    } else if (layer == "surface") {
      float_layer(out, glsl::OUT_SURF, kColour);
    } else if (layer == "volume") {
      float_layer(out, glsl::OUT_VOL, kColour);
    } else if (layer == "variance") {
      float_layer(out, glsl::OUT_VAR, kColour);
    } else if (layer == "virtual_point_depth") {
      float_layer(out, glsl::OUT_VPDEPTH, kScalar, distance_scale);
    } else if (layer == "depth") {
      float_layer(g, glsl::G_DEPTH, kScalar, distance_scale);
    } else if (layer == "motion") {
      float_layer(g, glsl::G_MOTION, kMotion, 1.f / 16.f);
    } else if (layer == "normal") {
      float_layer(g, glsl::G_NORMAL, kNormal);
    } else if (layer == "albedo") {
      float_layer(g, glsl::G_ALBEDO, kColour);
      push.exposure_scale = 1.f;
      push.tonemap = render::tonemap_op("clamp");
    } else if (layer == "surface_denoised") {
      src = &r.surface_denoiser()->output();
      push.mode = kColourHalf;
    } else if (layer == "volume_denoised") {
      src = &r.volume_denoiser()->output();
      push.mode = kColourHalf;
    } else if (layer == "surface_history") {
      history(*r.surface_denoiser(), s.denoise.surface.max_history);
    } else if (layer == "volume_history") {
      history(*r.volume_denoiser(), s.denoise.volume.max_history);
    } else if (layer == "volume_motion") {
      src = &r.volume_motion()->output();
      push.mode = kMotion;
      push.scale = 1.f / 16.f;
    } else if (layer == "guide_mean") {
      const glm::uvec2 grid =
          guiding::grid_size(s.guiding, uint32_t(s.render.width), uint32_t(s.render.height));
      gpu::Bindings states;  // the guide binds its states by name, as to the trace kernel
      r.guide().bind(states);
      src = states.find("guide_states")->buffer;
      push.mode = kGuide;
      push.stride = 0;
      push.scale = distance_scale;
      push.guide = glm::uvec4(grid, uint32_t(s.guiding.spacing), uint32_t(s.guiding.states));
    }
    if (layer == "denoised") {
      // The composite is what the tonemap pass wrote: the preview.
      gpu::copy_buffer(cmd, r.preview(), display, uint64_t(pixels) * 4);
    } else {
      if (push.mode == kColourHalf)
        gpu::require_strided(*src, pixels, 2, 0, 2, "view/display.comp", "half colour");
      else if (push.mode != kGuide)
        gpu::require_strided(*src, pixels, push.stride, push.offset, push.mode == kScalar ? 1 : 2,
                             "view/display.comp", layer.c_str());
      gpu::Bindings b;
      b.set("src", *src).set("display", display);
      kernel_.dispatch_1d(cmd, b, &push, pixels);
    }
  }
  if (timer) timer->end(cmd);
}

}  // namespace haze::view
