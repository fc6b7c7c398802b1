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
  const uint64_t bytes = uint64_t(grid_.x) * grid_.y * uint32_t(p.states) * 16;
  if (!states_.valid() || states_.size() != bytes) {
    const std::string format = fmt::format("{}x{} vertices x {} states x vec4", grid_.x, grid_.y, p.states);
    states_ = gpu::Buffer(ctx_, "guiding states", "guiding state", bytes, format);
    prev_states_ = gpu::Buffer(ctx_, "guiding states (previous frame)", "guiding state", bytes, format);
    reset = true;
  }
  if (reset) states_.fill_zero();
  if (!reproject_.valid())
    reproject_ = gpu::Kernel(ctx_, gpu::KernelDecl("guiding/guide_reproject.comp")
                                       .buffer("scene", sizeof(glsl::GpuScene))
                                       .buffer("motion", 16)
                                       .buffer("prev_states", 16, 16)
                                       .buffer("states", 16, 16));
}

void Guide::declare(gpu::KernelDecl& k) const {
  if (!active()) return;
  k.define("HAZE_GUIDING");
  k.buffer("guide_states", states_.size(), 16);
}

void Guide::bind(gpu::Bindings& b) const {
  if (active()) b.set("guide_states", states_);
}

void Guide::fill(glsl::GpuScene& g) const {
  const auto& gp = params_;
  g.guide = glm::vec4(gp.probability, gp.min_width, gp.prior_width, gp.prior_count);
  g.guide_grid = glm::uvec4(grid_, gp.states, gp.candidates);
  g.guide_learn = glm::vec4(float(gp.spacing), gp.learn ? 1.f : 0.f, float(gp.max_count), gp.min_alpha);
}

void Guide::start_frame(VkCommandBuffer cmd, gpu::Timer* timer, const gpu::Buffer& scene,
                        const gpu::Buffer* motion, bool has_previous) {
  if (!active()) return;
  if (!params_.temporal) {
    states_.fill_zero(cmd);
  } else if (has_previous && motion) {
    std::swap(states_, prev_states_);
    if (timer) timer->begin(cmd, "guide_reproject");
    const uint32_t states = grid_.x * grid_.y * uint32_t(params_.states);
    gpu::Bindings b;
    b.set("scene", scene).set("motion", *motion).set("prev_states", prev_states_).set("states", states_);
    reproject_.dispatch_1d(cmd, b, nullptr, states);
    if (timer) timer->end(cmd);
  }
  gpu::compute_barrier(cmd);
}

std::vector<glm::vec4> Guide::download() const {
  return states_.valid() ? states_.download_vector<glm::vec4>() : std::vector<glm::vec4>{};
}

}  // namespace haze::guiding
