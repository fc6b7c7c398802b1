// What the viewer can show: the frame's layers (the EXR's, by the same names where it has them), each drawn
// into the window's 8-bit image by one small pass (shaders/view/display.comp).
#pragma once

#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "render/renderer.hpp"

namespace haze::view {

struct LayerInfo {
  std::string name;  // "final", "volume", "surface_history", ...
  std::string help;  // one line for the selector's tooltip and docs/viewer.md
};
// Every layer, in the selector's order.
const std::vector<LayerInfo>& layers();
std::vector<std::string> layer_names();

class LayerDisplay {
 public:
  explicit LayerDisplay(gpu::Context& ctx);

  // Whether the renderer has `layer` now ("volume_history" needs the volume denoiser, ...).
  static bool available(const render::Renderer& r, const std::string& layer);
  // Records `layer` of the renderer's last resolved frame into `display` (RGBA8 per pixel, red in the low
  // byte, row 0 at the top). `extent` scales distances (depth, virtual point depth, the guide's mean) to
  // grey: the scene's size is white.
  void record(VkCommandBuffer cmd, gpu::Timer* timer, const render::Renderer& r, const std::string& layer,
              float extent, gpu::Buffer& display);

 private:
  gpu::Context& ctx_;
  gpu::Kernel kernel_;
};

}  // namespace haze::view
