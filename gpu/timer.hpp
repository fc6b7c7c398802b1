#pragma once
// GPU timestamps around passes, read back after the frame's submission completed.

#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace haze::gpu {

class Context;

struct TimerScope {
  std::string pass;
  double begin_ms, end_ms;  // relative to the first begin() since reset()
};

// Usage per frame: reset(cmd); begin(cmd, "pass"); ...dispatches...; end(cmd); ... submit and wait;
// read_ms(). Scopes do not nest. Where the queue has no timestamps every time reads as 0 (see supported()).
class Timer {
 public:
  explicit Timer(Context& ctx, uint32_t max_scopes = 256);
  ~Timer();
  Timer(Timer&& other) noexcept;
  Timer& operator=(Timer&& other) noexcept;
  Timer(const Timer&) = delete;
  Timer& operator=(const Timer&) = delete;

  void reset(VkCommandBuffer cmd);  // resets the query pool; call at the start of each recorded frame
  void begin(VkCommandBuffer cmd, const std::string& pass);
  void end(VkCommandBuffer cmd);
  std::vector<std::pair<std::string, double>> read_ms();  // (pass, ms) in record order
  std::vector<TimerScope> read_scopes();                  // with begin/end times, in record order
  bool supported() const { return pool_ != VK_NULL_HANDLE; }

 private:
  void release() noexcept;

  Context* ctx_ = nullptr;
  VkQueryPool pool_ = VK_NULL_HANDLE;
  uint32_t max_scopes_ = 0;
  uint64_t mask_ = 0;
  double period_ns_ = 0;
  std::vector<std::string> passes_;
  bool open_ = false;
};

}  // namespace haze::gpu
