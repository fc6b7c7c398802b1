// Split walks (render.walk_splits, docs/rendering.md): K walks from each camera sample's first medium vertex.
// A fixed K is a define of the trace kernel; K = 0 learns it (HAZE_WALK_SPLITS_AUTO): the trace reads the
// totals of earlier dispatches, chooses the dispatch's K from them and adds what it measured to a learning
// slot, which a fold pass adds to the totals after each dispatch. Only then are the statistics (ledger
// category "estimator state") and the fold kernel allocated.
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>

#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "scene/scene.hpp"

namespace haze::render {

class WalkSplits : public gpu::DeviceData {
 public:
  explicit WalkSplits(gpu::Context& ctx) : ctx_(ctx) {}

  // `active`: the default estimator with walks through a medium. The learned statistics survive a call
  // with the same setting and image size (camera moves keep them); `reset` empties them (a new run).
  void update(const scene::Scene& s, bool active, bool reset);
  bool learned() const { return stats_.valid(); }

  // HAZE_WALK_SPLITS K (learned: SPLIT_MAX, with HAZE_WALK_SPLITS_AUTO and the bindings "split_stats" and
  // "split_last").
  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
  // The trace's push constant split_index: dispatches since the statistics were emptied.
  uint32_t index() const { return index_; }
  // After each trace dispatch: folds its learning into the totals while the dispatches learn.
  void after_sample(VkCommandBuffer cmd);
  // The learned K* and what it came from (empty when K is not learned); waits for the device.
  nlohmann::json stats() const;

 private:
  gpu::Context& ctx_;
  int k_ = 1;  // render.walk_splits of the current scene (0: learned), 1 when inactive
  uint64_t pixels_ = 0;
  uint32_t index_ = 0;
  gpu::Buffer stats_, last_;
  gpu::Kernel fold_;
};

}  // namespace haze::render
