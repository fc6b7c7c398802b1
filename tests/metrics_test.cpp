// Error metrics on small images whose values are worked out by hand.
#include "eval/metrics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace haze::eval {
namespace {

Channels one_channel(const std::vector<float>& v) {
  return {v.data(), v.size(), 1, 0, 1};
}

// Two pixels, one channel: reference (1, 0), test (1.1, 0.1).
TEST(Metrics, HandComputedValues) {
  std::vector<float> ref = {1.f, 0.f}, x = {1.1f, 0.1f};
  Metrics m = compare(one_channel(x), one_channel(ref));
  // relMSE = (0.01 / 1.01 + 0.01 / 0.01) / 2
  EXPECT_NEAR(m.relmse, (0.01 / 1.01 + 1.0) / 2, 1e-6);
  // SMAPE = (0.1 / 2.11 + 0.1 / 0.11) / 2
  EXPECT_NEAR(m.smape, (0.1 / 2.11 + 0.1 / 0.11) / 2, 1e-6);
  EXPECT_NEAR(m.mse, 0.01, 1e-7);
  EXPECT_NEAR(m.psnr, 20.0, 1e-4);
  // Identical images: zero error, infinite PSNR.
  Metrics same = compare(one_channel(ref), one_channel(ref));
  EXPECT_EQ(same.relmse, 0.0);
  EXPECT_EQ(same.smape, 0.0);
  EXPECT_TRUE(std::isinf(same.psnr));
  EXPECT_EQ(same.to_json()["psnr"], "inf");
  // Strided rgb: channel 1 of a 3-float pixel at offset 0 counts like a plain channel.
  std::vector<float> a = {9, 1.1f, 9, 9, 0.1f, 9}, b = {7, 1, 7, 7, 0, 7};
  EXPECT_NEAR(relmse({a.data(), 2, 3, 1, 1}, {b.data(), 2, 3, 1, 1}), m.relmse, 1e-6);
}

// Frame-to-frame change of the test against that of the reference.
TEST(Metrics, TemporalStability) {
  std::vector<float> r0 = {1, 0}, r1 = {2, 0}, x0 = {1, 0}, x1 = {2, 0.5f};
  Temporal t = temporal({one_channel(x0), one_channel(x1)}, {one_channel(r0), one_channel(r1)});
  // dx = (1, 0.5), dr = (1, 0): ((0)^2 / 4.01 + 0.25 / 0.01) / 2; mean |dx| / mean |dr| = 1.5.
  EXPECT_NEAR(t.relmse_of_change, 12.5, 1e-6);
  EXPECT_NEAR(t.change_ratio, 1.5, 1e-9);
  // A static reference with a flickering test: infinite ratio, written as "inf".
  Temporal f = temporal({one_channel(x0), one_channel(x1)}, {one_channel(r0), one_channel(r0)});
  EXPECT_TRUE(std::isinf(f.change_ratio));
  EXPECT_EQ(f.to_json()["change_ratio"], "inf");
  // A test that follows its reference exactly.
  Temporal e = temporal({one_channel(r0), one_channel(r1)}, {one_channel(r0), one_channel(r1)});
  EXPECT_EQ(e.relmse_of_change, 0.0);
  EXPECT_EQ(e.change_ratio, 1.0);
}

}  // namespace
}  // namespace haze::eval
