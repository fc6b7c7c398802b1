#pragma once
// Frames in flight: a ring of command buffers, each with its fence and its timestamp queries, so that the
// host records frame k while the device still runs frames k-1 ... k-N+1. The host waits only when it
// reuses a slot, for the frame submitted N frames earlier; what must happen once a frame is finished (its
// timestamps, a readback, a screenshot) runs then, in submission order: timestamps arrive a frame late.

#include <vulkan/vulkan.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "gpu/timer.hpp"

namespace haze::gpu {

class Context;

class FrameRing {
 public:
  // `frames` in flight (at least 1), each timing up to `timer_scopes` passes.
  FrameRing(Context& ctx, std::string name, uint32_t frames = 2, uint32_t timer_scopes = 256);
  ~FrameRing();  // finishes: every frame in flight completes and its completions run
  FrameRing(const FrameRing&) = delete;
  FrameRing& operator=(const FrameRing&) = delete;

  // Starts recording the next frame into the oldest slot: waits for that slot's previous frame only, runs
  // its completions, resets its timer. The command buffer starts with a full memory barrier, so the frame
  // sees everything submitted before it.
  VkCommandBuffer begin();
  bool recording() const { return recording_; }
  VkCommandBuffer command_buffer() const;               // of the frame being recorded
  Timer& timer();                                       // of the frame being recorded
  uint64_t frame_number() const { return submitted_; }  // the frame being recorded (0, 1, ...)

  // Runs `done` on the host once the frame being recorded has finished on the device (from a later begin(),
  // poll() or finish(), in submission order).
  void on_complete(std::function<void()> done);
  // Every frame's timer scopes, on completion (before the frame's other completions).
  void on_times(std::function<void(const std::vector<TimerScope>&)> sink) { on_times_ = std::move(sink); }

  // Ends the frame (with a full barrier: later submissions see its writes) and submits it, waiting for and
  // signalling the given semaphores (a swapchain's).
  void submit(std::span<const VkSemaphore> wait = {}, std::span<const VkPipelineStageFlags> wait_stages = {},
              std::span<const VkSemaphore> signal = {});
  // Runs the completions of the frames already finished, oldest first, without waiting.
  void poll();
  // Waits for every frame in flight and runs their completions.
  void finish();
  // Waits for every frame in flight and drops their completions and timings (a run that failed: what they
  // would deliver is no longer wanted, and may refer to what the failure unwound).
  void discard();
  // Whether the next begin() would wait (its slot's frame is still running).
  bool would_wait() const;

  uint32_t frames() const { return uint32_t(slots_.size()); }
  uint32_t in_flight() const;
  uint64_t submitted() const { return submitted_; }
  double wait_ms() const { return wait_ms_; }  // host time spent waiting in begin() and finish()

 private:
  struct Slot;
  void complete(Slot& s);  // the slot's frame is finished: its completions run once

  Context& ctx_;
  std::string name_;
  std::vector<std::unique_ptr<Slot>> slots_;
  std::function<void(const std::vector<TimerScope>&)> on_times_;
  uint64_t submitted_ = 0;
  size_t next_ = 0;  // the slot begin() takes
  bool recording_ = false;
  double wait_ms_ = 0;
};

}  // namespace haze::gpu
