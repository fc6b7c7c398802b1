#include "guiding/guide.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <utility>

namespace haze::guiding {

glm::uvec2 grid_size(const GuidingParams& p, uint32_t width, uint32_t height) {
  // Vertex i sits at pixel coordinate i * spacing; one more column and row cover the far edge.
  uint32_t S = uint32_t(std::max(p.spacing, 1));
  return {width / S + 2, height / S + 2};
}

void Guide::update(const GuidingParams& p, uint32_t width, uint32_t height, bool active, bool reset) {
  params_ = p;
  width_ = width;
  height_ = height;
  grid_ = grid_size(p, width, height);
  if (!active) {
    states_ = gpu::Buffer();
    prev_states_ = gpu::Buffer();
    return;
  }
  const bool hist = p.model == "histogram";
  const uint32_t vertices = grid_.x * grid_.y;
  // Histogram: a vertex's floats padded to whole vec4s (the buffers are vec4 arrays for download()).
  const uint32_t B = uint32_t(p.bins);
  const uint64_t bytes =
      hist ? uint64_t(vertices) * hist_stride(B) * 4 : uint64_t(vertices) * uint32_t(p.states) * 16;
  const std::string format =
      hist ? fmt::format("{}x{} vertices x ({} bins, CDF, moments)", grid_.x, grid_.y, B)
           : fmt::format("{}x{} vertices x {} states x vec4", grid_.x, grid_.y, p.states);
  if (!states_.valid() || states_.size() != bytes || states_.format() != format) {
    states_ = gpu::Buffer(ctx_, "guiding states", "guiding state", bytes, format);
    prev_states_ = gpu::Buffer(ctx_, "guiding states (previous frame)", "guiding state", bytes, format);
    reset = true;
  }
  if (hist) {
    const uint64_t learn_bytes = uint64_t(vertices) * glsl::guide_learn_stride(B) * 4;
    if (!learn_.valid() || learn_.size() != learn_bytes) {
      learn_ = gpu::Buffer(ctx_, "guiding learning sums", "guiding state", learn_bytes,
                           fmt::format("{}x{} vertices x ({} bins, n, moments)", grid_.x, grid_.y, B));
      reset = true;
    }
  } else {
    learn_ = gpu::Buffer();
  }
  if (reset) {
    states_.fill_zero();
    if (hist) learn_.fill_zero();
  }
  const std::string bins = std::to_string(B);
  if (hist && (!fold_.valid() || fold_bins_ != B)) {
    fold_ = gpu::Kernel(ctx_, gpu::KernelDecl("guiding/guide_hist_fold.comp")
                                  .define("HAZE_GUIDE_BINS", bins)
                                  .buffer("scene", sizeof(glsl::GpuScene))
                                  .buffer("hist", 4)
                                  .buffer("learn", 4));
    reproject_ = gpu::Kernel(ctx_, gpu::KernelDecl("guiding/guide_reproject.comp")
                                       .define("HAZE_GUIDE_HIST")
                                       .define("HAZE_GUIDE_BINS", bins)
                                       .buffer("scene", sizeof(glsl::GpuScene))
                                       .buffer("motion", 16)
                                       .buffer("prev_states", 4)
                                       .buffer("states", 4));
    fold_bins_ = B;
  }
  if (!hist && (!reproject_.valid() || fold_bins_ != 0)) {
    reproject_ = gpu::Kernel(ctx_, gpu::KernelDecl("guiding/guide_reproject.comp")
                                       .buffer("scene", sizeof(glsl::GpuScene))
                                       .buffer("motion", 16)
                                       .buffer("prev_states", 16, 16)
                                       .buffer("states", 16, 16));
    fold_ = gpu::Kernel();
    fold_bins_ = 0;
  }
}

uint32_t Guide::hist_stride(uint32_t bins) {
  return (glsl::guide_hist_stride(bins) + 3) / 4 * 4;
}

void Guide::declare(gpu::KernelDecl& k) const {
  if (!active()) return;
  k.define("HAZE_GUIDING");
  if (histogram()) {
    k.define("HAZE_GUIDE_HIST");
    k.define("HAZE_GUIDE_BINS", std::to_string(params_.bins));
    // Without float atomics concurrent additions to one bin may lose some (still a valid histogram).
    if (ctx_.features().atomic_float_add) k.define("HAZE_GUIDE_ATOMIC_FLOAT");
    k.buffer("guide_hist", states_.size(), 4);
    k.buffer("guide_learn", learn_.size(), 4);
  } else {
    k.buffer("guide_states", states_.size(), 16);
  }
}

void Guide::bind(gpu::Bindings& b) const {
  if (histogram())
    b.set("guide_hist", states_).set("guide_learn", learn_);
  else if (active())
    b.set("guide_states", states_);
}

void Guide::fill(glsl::GpuScene& g) const {
  const auto& gp = params_;
  g.guide = glm::vec4(gp.probability, gp.min_width, gp.prior_width, gp.prior_count);
  g.guide_grid = glm::uvec4(grid_, gp.states, gp.candidates);
  g.guide_learn = glm::vec4(float(gp.spacing), gp.learn ? 1.f : 0.f, float(gp.max_count), gp.min_alpha);
  if (gp.model == "histogram") {
    // guide.y: choose P per vertex (0/1); guide_grid.z: floats per vertex.
    g.guide = glm::vec4(gp.probability, gp.choose_probability ? 1.f : 0.f, 0, 0);
    g.guide_grid = glm::uvec4(grid_, hist_stride(uint32_t(gp.bins)), 0);
  }
}

void Guide::start_frame(VkCommandBuffer cmd, gpu::Timer* timer, const gpu::Buffer& scene,
                        const gpu::Buffer* motion, bool has_previous) {
  if (!active()) return;
  if (!params_.temporal) {
    states_.fill_zero(cmd);
  } else if (has_previous && motion) {
    std::swap(states_, prev_states_);
    if (timer) timer->begin(cmd, "guide_reproject");
    const uint32_t states =
        grid_.x * grid_.y * (histogram() ? hist_stride(uint32_t(params_.bins)) : uint32_t(params_.states));
    gpu::Bindings b;
    b.set("scene", scene).set("motion", *motion).set("prev_states", prev_states_).set("states", states_);
    reproject_.dispatch_1d(cmd, b, nullptr, states);
    if (timer) timer->end(cmd);
  }
  gpu::compute_barrier(cmd);
}

void Guide::after_sample(VkCommandBuffer cmd, const gpu::Buffer& scene) {
  if (!histogram()) return;
  gpu::Bindings b;
  b.set("scene", scene).set("hist", states_).set("learn", learn_);
  fold_.dispatch_1d(cmd, b, nullptr, grid_.x * grid_.y);
  gpu::compute_barrier(cmd);
}

std::vector<glm::vec4> Guide::download() const {
  return states_.valid() ? states_.download_vector<glm::vec4>() : std::vector<glm::vec4>{};
}

}  // namespace haze::guiding
