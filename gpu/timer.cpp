#include "gpu/timer.hpp"

#include <fmt/format.h>

#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/vk_struct.hpp"

namespace haze::gpu {

Timer::Timer(Context& ctx, uint32_t max_scopes) : ctx_(&ctx), max_scopes_(max_scopes) {
  if (max_scopes == 0) throw Error("Timer needs at least one scope");
  uint32_t bits = ctx.timestamp_valid_bits();
  if (bits == 0) return;  // no timestamps on this queue: times read as 0
  mask_ = bits >= 64 ? ~uint64_t{0} : (uint64_t{1} << bits) - 1;
  period_ns_ = ctx.timestamp_period_ns();
  auto info = vk_struct<VkQueryPoolCreateInfo>(VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO);
  info.queryType = VK_QUERY_TYPE_TIMESTAMP;
  info.queryCount = 2 * max_scopes;
  HAZE_VK(vkCreateQueryPool(ctx.device(), &info, nullptr, &pool_));
}

void Timer::release() noexcept {
  if (ctx_ && pool_) vkDestroyQueryPool(ctx_->device(), pool_, nullptr);
  pool_ = VK_NULL_HANDLE;
  ctx_ = nullptr;
}

Timer::~Timer() {
  release();
}

Timer::Timer(Timer&& o) noexcept
    : ctx_(std::exchange(o.ctx_, nullptr)),
      pool_(std::exchange(o.pool_, VK_NULL_HANDLE)),
      max_scopes_(o.max_scopes_),
      mask_(o.mask_),
      period_ns_(o.period_ns_),
      passes_(std::move(o.passes_)),
      open_(std::exchange(o.open_, false)) {}

Timer& Timer::operator=(Timer&& o) noexcept {
  if (this != &o) {
    release();
    ctx_ = std::exchange(o.ctx_, nullptr);
    pool_ = std::exchange(o.pool_, VK_NULL_HANDLE);
    max_scopes_ = o.max_scopes_;
    mask_ = o.mask_;
    period_ns_ = o.period_ns_;
    passes_ = std::move(o.passes_);
    open_ = std::exchange(o.open_, false);
  }
  return *this;
}

void Timer::reset(VkCommandBuffer cmd) {
  if (!ctx_) throw Error("reset of an empty gpu::Timer");
  passes_.clear();
  open_ = false;
  if (pool_) vkCmdResetQueryPool(cmd, pool_, 0, 2 * max_scopes_);
}

void Timer::begin(VkCommandBuffer cmd, const std::string& pass) {
  if (!ctx_) throw Error("begin on an empty gpu::Timer");
  if (open_)
    throw Error(
        fmt::format("Timer::begin('{}') while '{}' is open: scopes do not nest", pass, passes_.back()));
  if (passes_.size() >= max_scopes_)
    throw Error(fmt::format("Timer::begin('{}'): more than {} scopes since reset()", pass, max_scopes_));
  // BOTTOM_OF_PIPE: written once all earlier commands finished, so a scope does not absorb the previous pass.
  if (pool_)
    vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, pool_,
                        static_cast<uint32_t>(2 * passes_.size()));
  passes_.push_back(pass);
  open_ = true;
}

void Timer::end(VkCommandBuffer cmd) {
  if (!open_) throw Error("Timer::end() without begin()");
  if (pool_)
    vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, pool_,
                        static_cast<uint32_t>(2 * passes_.size() - 1));
  open_ = false;
}

std::vector<TimerScope> Timer::read_scopes() {
  if (open_) throw Error(fmt::format("Timer read while '{}' is still open", passes_.back()));
  std::vector<TimerScope> out;
  if (passes_.empty()) return out;
  if (!pool_) {
    for (const auto& p : passes_) out.push_back({p, 0.0, 0.0});
    return out;
  }
  uint32_t n = static_cast<uint32_t>(2 * passes_.size());
  std::vector<uint64_t> data(2 * n);  // (value, availability) per query
  VkResult r = vkGetQueryPoolResults(ctx_->device(), pool_, 0, n, data.size() * sizeof(uint64_t), data.data(),
                                     2 * sizeof(uint64_t),
                                     VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WITH_AVAILABILITY_BIT);
  if (r != VK_SUCCESS && r != VK_NOT_READY) vk_check(r, "vkGetQueryPoolResults");
  for (uint32_t q = 0; q < n; ++q)
    if (data[2 * q + 1] == 0)
      throw Error(
          fmt::format("timestamps of '{}' are not available: read the Timer after its submission completed",
                      passes_[q / 2]));
  const uint64_t t0 = data[0];
  const auto ms = [&](uint64_t t) { return static_cast<double>((t - t0) & mask_) * period_ns_ * 1e-6; };
  for (size_t i = 0; i < passes_.size(); ++i)
    out.push_back({passes_[i], ms(data[4 * i]), ms(data[4 * i + 2])});
  return out;
}

std::vector<std::pair<std::string, double>> Timer::read_ms() {
  std::vector<std::pair<std::string, double>> out;
  for (auto& s : read_scopes()) out.emplace_back(std::move(s.pass), s.end_ms - s.begin_ms);
  return out;
}

}  // namespace haze::gpu
