#include "render/walk_splits.hpp"

#include <array>
#include <string>

#include "shaders/glsl.hpp"

namespace haze::render {

static_assert(glsl::SPLIT_SLOT == 8, "walk_splits_fold.comp folds the slot with 8 invocations");

void WalkSplits::update(const scene::Scene& s, bool active, bool reset) {
  k_ = active ? s.render.walk_splits : 1;
  const uint64_t pixels = uint64_t(s.render.width) * uint64_t(s.render.height);
  if (k_ != 0) {
    stats_ = gpu::Buffer();
    last_ = gpu::Buffer();
    fold_ = gpu::Kernel();
    pixels_ = 0;
    return;
  }
  if (!fold_.valid())
    fold_ = gpu::Kernel(
        ctx_,
        gpu::KernelDecl("volume/walk_splits_fold.comp").buffer("split_stats", 2 * glsl::SPLIT_SLOT * 4));
  if (!stats_.valid()) {
    stats_ = gpu::Buffer(ctx_, "walk split statistics", "estimator state", 2 * glsl::SPLIT_SLOT * 4,
                         "f32 totals, learning (walk_splits_layout.glsl)");
    reset = true;
  }
  if (pixels != pixels_) {
    last_ = gpu::Buffer(ctx_, "walk split last samples", "estimator state", pixels * 16,
                        "vec4 (sum, count, last, its K) per pixel");
    pixels_ = pixels;
    reset = true;
  }
  if (reset) {
    stats_.fill_zero();
    last_.fill_zero();
    index_ = 0;
  }
}

void WalkSplits::declare(gpu::KernelDecl& k) const {
  if (k_ == 1) return;
  if (k_ > 1) {
    k.define("HAZE_WALK_SPLITS", std::to_string(k_));
    return;
  }
  k.define("HAZE_WALK_SPLITS", std::to_string(glsl::SPLIT_MAX));
  k.define("HAZE_WALK_SPLITS_AUTO");
  // Without float atomics concurrent additions may be lost (a noisier K; every estimate stays unbiased).
  if (ctx_.features().atomic_float_add) k.define("HAZE_SPLIT_ATOMIC_FLOAT");
  // One addition per subgroup instead of one per invocation: lavapipe's lanes would queue on one address.
  if (ctx_.features().subgroup_arithmetic) k.define("HAZE_SPLIT_SUBGROUP");
  k.buffer("split_stats", stats_.size(), 4);
  k.buffer("split_last", last_.size(), 16);
}

void WalkSplits::bind(gpu::Bindings& b) const {
  if (learned()) b.set("split_stats", stats_).set("split_last", last_);
}

void WalkSplits::after_sample(VkCommandBuffer cmd) {
  if (!learned() || !glsl::walk_splits_learning(index_++, uint32_t(pixels_))) return;
  gpu::compute_barrier(cmd);
  gpu::Bindings b;
  b.set("split_stats", stats_);
  fold_.dispatch(cmd, b, nullptr, 1);
  gpu::compute_barrier(cmd);
}

nlohmann::json WalkSplits::stats() const {
  if (!learned()) return nlohmann::json::object();
  std::array<float, glsl::SPLIT_SLOT> s{};  // the totals
  stats_.download(s.data(), sizeof(s), glsl::SPLIT_TOTALS * 4);
  const float k = glsl::walk_splits_k(s[glsl::SPLIT_WV_WALK], s[glsl::SPLIT_WV_BETWEEN], s[glsl::SPLIT_N_VAR],
                                      s[glsl::SPLIT_COST_CAMERA], s[glsl::SPLIT_COST_WALK]);
  const double n = s[glsl::SPLIT_N], n_var = s[glsl::SPLIT_N_VAR];
  return {{"k", k},
          {"samples", n},
          {"relative_variance_walk", n_var > 0 ? s[glsl::SPLIT_WV_WALK] / n_var : 0.0},
          {"relative_variance_between", n_var > 0 ? s[glsl::SPLIT_WV_BETWEEN] / n_var : 0.0},
          {"cost_camera", n > 0 ? s[glsl::SPLIT_COST_CAMERA] / n : 0.0},
          {"cost_per_walk", n > 0 ? s[glsl::SPLIT_COST_WALK] / n : 0.0}};
}

}  // namespace haze::render
