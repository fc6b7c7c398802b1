#include "gpu/frames.hpp"

#include <fmt/format.h>

#include <chrono>

#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/vk_struct.hpp"

namespace haze::gpu {

struct FrameRing::Slot {
  Context& ctx;
  VkCommandPool pool = VK_NULL_HANDLE;
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  VkFence fence = VK_NULL_HANDLE;
  Timer timer;
  bool pending = false;  // submitted, completions not yet run
  std::vector<std::function<void()>> done;

  Slot(Context& c, uint32_t scopes) : ctx(c), timer(c, scopes) {
    auto pinfo = vk_struct<VkCommandPoolCreateInfo>(VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO);
    pinfo.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pinfo.queueFamilyIndex = ctx.queue_family();
    HAZE_VK(vkCreateCommandPool(ctx.device(), &pinfo, nullptr, &pool));
    auto ainfo = vk_struct<VkCommandBufferAllocateInfo>(VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO);
    ainfo.commandPool = pool;
    ainfo.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    ainfo.commandBufferCount = 1;
    HAZE_VK(vkAllocateCommandBuffers(ctx.device(), &ainfo, &cmd));
    auto finfo = vk_struct<VkFenceCreateInfo>(VK_STRUCTURE_TYPE_FENCE_CREATE_INFO);
    HAZE_VK(vkCreateFence(ctx.device(), &finfo, nullptr, &fence));
  }
  ~Slot() {
    if (fence) vkDestroyFence(ctx.device(), fence, nullptr);
    if (pool) vkDestroyCommandPool(ctx.device(), pool, nullptr);
  }
};

namespace {

// Everything written before is visible to everything after, on the device and to the host.
void full_barrier(VkCommandBuffer cmd) {
  auto b = vk_struct<VkMemoryBarrier>(VK_STRUCTURE_TYPE_MEMORY_BARRIER);
  b.srcAccessMask = VK_ACCESS_MEMORY_WRITE_BIT;
  b.dstAccessMask = VK_ACCESS_HOST_READ_BIT | VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                       VK_PIPELINE_STAGE_HOST_BIT | VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, 1, &b, 0, nullptr,
                       0, nullptr);
}

double ms_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

FrameRing::FrameRing(Context& ctx, std::string name, uint32_t frames, uint32_t timer_scopes)
    : ctx_(ctx), name_(std::move(name)) {
  if (frames == 0) throw Error(fmt::format("frame ring '{}': at least one frame in flight", name_));
  for (uint32_t i = 0; i < frames; ++i) slots_.push_back(std::make_unique<Slot>(ctx, timer_scopes));
}

FrameRing::~FrameRing() {
  try {
    finish();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "haze: frame ring '%s': %s\n", name_.c_str(), e.what());
  }
  for (auto& s : slots_)
    if (s->pending) {  // a completion threw: the fence may still be tracked
      vkWaitForFences(ctx_.device(), 1, &s->fence, VK_TRUE, UINT64_MAX);
      ctx_.untrack_in_flight(s->fence);
    }
  if (recording_) vkEndCommandBuffer(slots_[next_]->cmd);
}

void FrameRing::complete(Slot& s) {
  if (!s.pending) return;
  ctx_.untrack_in_flight(s.fence);
  s.pending = false;
  std::vector<std::function<void()>> done = std::move(s.done);
  s.done.clear();
  if (on_times_) on_times_(s.timer.read_scopes());
  for (auto& f : done) f();
}

VkCommandBuffer FrameRing::begin() {
  if (recording_) throw Error(fmt::format("frame ring '{}': begin() while a frame is being recorded", name_));
  Slot& s = *slots_[next_];
  if (s.pending) {
    const auto t0 = std::chrono::steady_clock::now();
    HAZE_VK(vkWaitForFences(ctx_.device(), 1, &s.fence, VK_TRUE, UINT64_MAX));
    wait_ms_ += ms_since(t0);
    complete(s);
  }
  HAZE_VK(vkResetCommandBuffer(s.cmd, 0));
  auto info = vk_struct<VkCommandBufferBeginInfo>(VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO);
  info.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  HAZE_VK(vkBeginCommandBuffer(s.cmd, &info));
  recording_ = true;
  full_barrier(s.cmd);
  s.timer.reset(s.cmd);
  return s.cmd;
}

VkCommandBuffer FrameRing::command_buffer() const {
  if (!recording_) throw Error(fmt::format("frame ring '{}': no frame is being recorded", name_));
  return slots_[next_]->cmd;
}

Timer& FrameRing::timer() {
  if (!recording_) throw Error(fmt::format("frame ring '{}': no frame is being recorded", name_));
  return slots_[next_]->timer;
}

void FrameRing::on_complete(std::function<void()> done) {
  if (!recording_) throw Error(fmt::format("frame ring '{}': on_complete() outside a frame", name_));
  slots_[next_]->done.push_back(std::move(done));
}

void FrameRing::submit(std::span<const VkSemaphore> wait, std::span<const VkPipelineStageFlags> wait_stages,
                       std::span<const VkSemaphore> signal) {
  if (!recording_) throw Error(fmt::format("frame ring '{}': submit() without begin()", name_));
  if (wait.size() != wait_stages.size())
    throw Error(fmt::format("frame ring '{}': {} wait semaphores with {} stages", name_, wait.size(),
                            wait_stages.size()));
  Slot& s = *slots_[next_];
  recording_ = false;
  full_barrier(s.cmd);
  HAZE_VK(vkEndCommandBuffer(s.cmd));
  HAZE_VK(vkResetFences(ctx_.device(), 1, &s.fence));
  auto info = vk_struct<VkSubmitInfo>(VK_STRUCTURE_TYPE_SUBMIT_INFO);
  info.waitSemaphoreCount = uint32_t(wait.size());
  info.pWaitSemaphores = wait.data();
  info.pWaitDstStageMask = wait_stages.data();
  info.commandBufferCount = 1;
  info.pCommandBuffers = &s.cmd;
  info.signalSemaphoreCount = uint32_t(signal.size());
  info.pSignalSemaphores = signal.data();
  ctx_.submit(info, s.fence);
  s.pending = true;
  ctx_.track_in_flight(s.fence);
  ++submitted_;
  next_ = (next_ + 1) % slots_.size();
}

void FrameRing::poll() {
  // Oldest first: the slot begin() takes next is the oldest one in flight.
  for (size_t i = 0; i < slots_.size(); ++i) {
    Slot& s = *slots_[(next_ + i) % slots_.size()];
    if (!s.pending) continue;
    if (vkGetFenceStatus(ctx_.device(), s.fence) != VK_SUCCESS) return;
    complete(s);
  }
}

void FrameRing::finish() {
  for (size_t i = 0; i < slots_.size(); ++i) {
    Slot& s = *slots_[(next_ + i) % slots_.size()];
    if (!s.pending) continue;
    const auto t0 = std::chrono::steady_clock::now();
    HAZE_VK(vkWaitForFences(ctx_.device(), 1, &s.fence, VK_TRUE, UINT64_MAX));
    wait_ms_ += ms_since(t0);
    complete(s);
  }
}

void FrameRing::discard() {
  for (auto& s : slots_) {
    if (!s->pending) continue;
    HAZE_VK(vkWaitForFences(ctx_.device(), 1, &s->fence, VK_TRUE, UINT64_MAX));
    ctx_.untrack_in_flight(s->fence);
    s->pending = false;
    s->done.clear();
  }
}

bool FrameRing::would_wait() const {
  const Slot& s = *slots_[next_];
  return s.pending && vkGetFenceStatus(ctx_.device(), s.fence) != VK_SUCCESS;
}

uint32_t FrameRing::in_flight() const {
  uint32_t n = 0;
  for (const auto& s : slots_) n += s->pending ? 1 : 0;
  return n;
}

}  // namespace haze::gpu
