// Frames in flight (gpu::FrameRing) and the host's safety net around them (Context::wait_in_flight): the
// host waits only for the frame it reuses a slot of, completions (timestamps, readbacks) run a frame late
// and in submission order, and host access to memory a frame in flight uses waits for it.
#include <gtest/gtest.h>

#include <vector>

#include "gpu/gpu.hpp"

namespace haze {
namespace {

gpu::Context& ctx() {
  static gpu::Context c;
  return c;
}

// Two frames in flight: begin() of frame k waits for frame k-2 only and runs its completions (its timer
// scopes first); frame k-1's run later. Injected defect caught: begin() finishing every frame in flight
// (frame 1's completion would already have run when frame 2 began).
TEST(FrameRing, CompletionsRunAFrameLateInOrder) {
  gpu::FrameRing ring(ctx(), "test", 2, 4);
  std::vector<int> done;
  std::vector<std::string> times;
  ring.on_times([&](const std::vector<gpu::TimerScope>& t) {
    for (const auto& s : t) times.push_back(s.pass);
  });
  gpu::Buffer b(ctx(), "frame test", "test", 1 << 20);
  for (int f = 0; f < 3; ++f) {
    VkCommandBuffer cmd = ring.begin();
    EXPECT_EQ(done.size(), size_t(f >= 2 ? f - 1 : 0)) << "frame " << f;
    ring.timer().begin(cmd, "fill" + std::to_string(f));
    b.fill(cmd, uint32_t(f));
    ring.timer().end(cmd);
    ring.on_complete([&done, f] { done.push_back(f); });
    ring.submit();
  }
  EXPECT_EQ(done, std::vector<int>({0}));
  EXPECT_EQ(times, std::vector<std::string>({"fill0"}));
  ring.finish();
  EXPECT_EQ(done, std::vector<int>({0, 1, 2}));
  EXPECT_EQ(times, std::vector<std::string>({"fill0", "fill1", "fill2"}));
  EXPECT_EQ(ring.in_flight(), 0u);
  EXPECT_EQ(ctx().validation_messages(), 0u);
}

// A host read of a buffer that a frame in flight writes waits for that frame (and is counted); so does the
// buffer's destruction (the validation layer would report a buffer destroyed while in use). Injected defect
// caught: Buffer::download without Context::wait_in_flight (it read the zeros from before the fill).
TEST(FrameRing, HostAccessWaitsForTheFramesInFlight) {
  gpu::FrameRing ring(ctx(), "test", 2, 4);
  const uint64_t waits = ctx().host_waits();
  auto big = std::make_unique<gpu::Buffer>(ctx(), "big fill", "test", uint64_t(96) << 20);
  big->fill_zero();
  for (uint32_t value : {7u, 9u}) {
    VkCommandBuffer cmd = ring.begin();
    for (int i = 0; i < 8; ++i) big->fill(cmd, value);  // a few milliseconds of work
    ring.submit();
    uint32_t first[4];
    big->download(first, sizeof first);
    EXPECT_EQ(first[0], value);
    EXPECT_EQ(first[3], value);
  }
  EXPECT_GE(ctx().host_waits(), waits + 1);
  VkCommandBuffer cmd = ring.begin();
  for (int i = 0; i < 8; ++i) big->fill(cmd, 3u);
  ring.submit();
  big.reset();  // waits for the frame
  ring.finish();
  EXPECT_EQ(ctx().validation_messages(), 0u);
}

// A failed run drops what waits for its frames: discard() waits for them but runs no completion (they may
// refer to what the failure unwound; `haze render` of a sequence whose second frame fails crashed on the
// first frame's). Injected defect caught: discard() as finish() (the completion ran).
TEST(FrameRing, DiscardWaitsAndDropsCompletions) {
  gpu::FrameRing ring(ctx(), "test", 2, 4);
  gpu::Buffer b(ctx(), "discard test", "test", 1 << 20);
  int ran = 0;
  for (int f = 0; f < 2; ++f) {
    VkCommandBuffer cmd = ring.begin();
    b.fill(cmd, 5u);
    ring.on_complete([&ran] { ++ran; });
    ring.submit();
  }
  ring.discard();
  EXPECT_EQ(ring.in_flight(), 0u);
  ring.finish();
  EXPECT_EQ(ran, 0);
  EXPECT_EQ(b.download_vector<uint32_t>()[0], 5u);
  EXPECT_EQ(ctx().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze
