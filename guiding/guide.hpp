// The distance-guiding state on the device (docs/guiding.md): per vertex of a screen-space grid, either a
// histogram over the ray (model "histogram": the trace kernel samples it and adds to a learning buffer that
// a fold pass merges after each dispatch) or K states {W, N, m1, m2} (model "gaussian", read and written by
// the trace kernel), carried to the next frame through the volume motion vectors by a reproject pass.
// Without guiding nothing is allocated and no kernel has guide code.
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
  bool histogram() const { return active() && params_.model == "histogram"; }

  // HAZE_GUIDING and the binding "guide_states" (gaussian), or HAZE_GUIDE_HIST, HAZE_GUIDE_BINS and the
  // bindings "guide_hist" and "guide_learn" (histogram).
  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
  void fill(glsl::GpuScene& g) const;  // guide, guide_grid, guide_learn

  // Before the frame's first sample: an empty grid without temporal reuse, else (when a previous frame
  // exists) each vertex takes the states of the previous frame's vertex its virtual point came from.
  // `scene` is the frame's scene block, `motion` the volume motion (vec4 per pixel).
  void start_frame(VkCommandBuffer cmd, gpu::Timer* timer, const gpu::Buffer& scene,
                   const gpu::Buffer* motion, bool has_previous);
  // After each trace dispatch (histogram model; nothing otherwise): folds the dispatch's learning into the
  // histograms and chooses each vertex's P. Recorded inside the trace timer: it is the guide's cost.
  void after_sample(VkCommandBuffer cmd, const gpu::Buffer& scene);
  // Gaussian: the K states per vertex; histogram: the vertices' data as floats (guide.glsl layout), in vec4s.
  std::vector<glm::vec4> download() const;
  // Floats per vertex of the histogram model (guide.glsl layout, padded to whole vec4s).
  static uint32_t hist_stride(uint32_t bins);

 private:
  gpu::Context& ctx_;
  GuidingParams params_;
  glm::uvec2 grid_{0};
  uint32_t width_ = 0, height_ = 0;
  gpu::Buffer states_, prev_states_;  // histogram: the vertices' histograms
  gpu::Buffer learn_;                 // histogram: what the current dispatch learned
  gpu::Kernel reproject_, fold_;
  uint32_t fold_bins_ = 0;  // the bins the histogram kernels were made for (0: gaussian kernels)
};

}  // namespace haze::guiding
