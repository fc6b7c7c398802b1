// FLIP (eval/flip.cpp) on generated images: zero for identical images, symmetry, monotonicity in the
// added error, values worked out by hand from the papers' formulas, and the error map.
#include "eval/flip.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

namespace haze::eval {
namespace {

constexpr int W = 40, H = 32;

Channels rgb(const std::vector<float>& v) {
  return {v.data(), v.size() / 3, 3, 0, 3};
}

std::vector<float> uniform(float r, float g, float b, int w = 8, int h = 8) {
  std::vector<float> v;
  for (int p = 0; p < w * h; ++p) v.insert(v.end(), {r, g, b});
  return v;
}

// A test scene: a soft gradient, a bright square with sharp edges and some HDR values above 1.
std::vector<float> scene() {
  std::vector<float> v;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const bool square = x >= 10 && x < 22 && y >= 8 && y < 20;
      const float base = 0.05f + 0.4f * float(x) / W;
      v.insert(v.end(),
               {square ? 3.f : base, square ? 2.5f : 0.6f * base, square ? 0.8f : 0.3f + 0.2f * y / H});
    }
  return v;
}

std::vector<float> noise(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> d(0.f, 1.f);
  std::vector<float> v(n);
  for (float& x : v) x = d(rng);
  return v;
}

// x + amplitude * n, kept non-negative.
std::vector<float> plus(const std::vector<float>& x, const std::vector<float>& n, float amplitude) {
  std::vector<float> v(x.size());
  for (size_t i = 0; i < v.size(); ++i) v[i] = std::max(0.f, x[i] + amplitude * n[i]);
  return v;
}

TEST(Flip, ZeroForIdenticalImages) {
  const std::vector<float> a = scene(), b = a;
  EXPECT_EQ(flip_ldr(rgb(a), rgb(b), W, H).mean, 0.0);
  EXPECT_EQ(flip_hdr(rgb(a), rgb(b), W, H).mean, 0.0);
  // One grey channel (e.g. transmittance.Y), and flat images, where the filters must not make features.
  std::vector<float> grey(W * H);
  for (size_t p = 0; p < grey.size(); ++p) grey[p] = a[p * 3];
  const Channels g{grey.data(), grey.size(), 1, 0, 1};
  EXPECT_EQ(flip_ldr(g, g, W, H).mean, 0.0);
  EXPECT_EQ(flip_hdr(g, g, W, H).mean, 0.0);
  const std::vector<float> flat = uniform(0.3f, 0.2f, 0.1f);
  EXPECT_EQ(flip_hdr(rgb(flat), rgb(flat), 8, 8).mean, 0.0);
  EXPECT_GT(flip_ldr(rgb(plus(a, noise(a.size(), 1), 0.05f)), rgb(a), W, H).mean, 0.0);
}

// LDR-FLIP is symmetric: HyAB is a distance and the feature term compares |features(test)| with
// |features(ref)| through an absolute difference (HPG 2020, eqs. 4 and 8). HDR-FLIP is not in general:
// the exposure range is taken from the reference alone (EG 2021, section 3); it is symmetric where
// both images have the same maximum and median luminance.
TEST(Flip, SymmetryWhereThePapersHaveIt) {
  const std::vector<float> a = scene(), b = plus(a, noise(a.size(), 2), 0.1f);
  FlipOptions o;
  o.want_map = true;
  const FlipResult ab = flip_ldr(rgb(a), rgb(b), W, H, o), ba = flip_ldr(rgb(b), rgb(a), W, H, o);
  EXPECT_EQ(ab.mean, ba.mean);
  EXPECT_EQ(ab.map, ba.map);

  // Same pixels in reverse order: same luminance statistics, hence the same exposures both ways.
  std::vector<float> r(a.size());
  for (size_t p = 0; p < a.size() / 3; ++p)
    for (int c = 0; c < 3; ++c) r[p * 3 + c] = a[(a.size() / 3 - 1 - p) * 3 + c];
  EXPECT_EQ(flip_hdr(rgb(a), rgb(r), W, H).mean, flip_hdr(rgb(r), rgb(a), W, H).mean);

  // A brighter test seen through the reference's exposures differs from the reverse.
  std::vector<float> bright(a.size());
  for (size_t i = 0; i < a.size(); ++i) bright[i] = 4 * a[i];
  EXPECT_NE(flip_hdr(rgb(bright), rgb(a), W, H).mean, flip_hdr(rgb(a), rgb(bright), W, H).mean);
}

TEST(Flip, MonotoneInAddedError) {
  const std::vector<float> ref = scene(), n = noise(ref.size(), 7), one(ref.size(), 1.f);
  double last_ldr = 0, last_hdr = 0, last_ldr_shift = 0, last_hdr_shift = 0;
  for (float amplitude : {0.f, 0.01f, 0.03f, 0.1f, 0.3f, 1.f}) {
    const std::vector<float> noisy = plus(ref, n, amplitude), shifted = plus(ref, one, amplitude);
    const double ldr = flip_ldr(rgb(noisy), rgb(ref), W, H).mean,
                 hdr = flip_hdr(rgb(noisy), rgb(ref), W, H).mean;
    const double ldr_shift = flip_ldr(rgb(shifted), rgb(ref), W, H).mean,
                 hdr_shift = flip_hdr(rgb(shifted), rgb(ref), W, H).mean;
    EXPECT_GE(ldr, last_ldr) << "noise " << amplitude;
    EXPECT_GE(hdr, last_hdr) << "noise " << amplitude;
    EXPECT_GE(ldr_shift, last_ldr_shift) << "offset " << amplitude;
    EXPECT_GE(hdr_shift, last_hdr_shift) << "offset " << amplitude;
    last_ldr = ldr, last_hdr = hdr, last_ldr_shift = ldr_shift, last_hdr_shift = hdr_shift;
  }
  EXPECT_GT(last_ldr, 0.1);
  EXPECT_GT(last_hdr, 0.1);
}

// Uniform images: the CSF leaves them as they are and there are no features, so FLIP is the remapped
// colour error of one HyAB distance. Hunt-adjusted L*a*b* of green is (87.736, -75.59, 72.98), of blue
// (32.298, 25.58, -34.84): cmax = 203.3017^0.7 = 41.2761, pc cmax = 16.5104.
TEST(Flip, HandComputedUniformImages) {
  auto ldr = [](const std::vector<float>& t, const std::vector<float>& r) {
    return flip_ldr(rgb(t), rgb(r), 8, 8).mean;
  };
  // Green against blue: their distance is cmax itself, the top of the range.
  EXPECT_NEAR(ldr(uniform(0, 1, 0), uniform(0, 0, 1)), 1.0, 1e-5);
  // Black against white: HyAB = |0 - 100| = 100, 100^0.7 = 25.1189 > pc cmax, so
  // 0.95 + (25.1189 - 16.5104) / (41.2761 - 16.5104) * 0.05 = 0.967380.
  EXPECT_NEAR(ldr(uniform(0, 0, 0), uniform(1, 1, 1)), 0.967380, 1e-5);
  // Grey 0.25 against 0.5 (linear): L* = 116 * 0.25^(1/3) - 16 = 57.0754 and 116 * 0.5^(1/3) - 16 =
  // 76.0693, HyAB = 18.9938, ^0.7 = 7.85288 < pc cmax, so 0.95 / 16.5104 * 7.85288 = 0.451850.
  EXPECT_NEAR(ldr(uniform(0.25f, 0.25f, 0.25f), uniform(0.5f, 0.5f, 0.5f)), 0.451850, 1e-5);
  // LDR-FLIP clamps HDR values: 7 reads as 1.
  EXPECT_NEAR(ldr(uniform(0, 0, 0), uniform(7, 7, 7)), 0.967380, 1e-5);

  // HDR-FLIP of the same greys with 0.5 as reference: maximum = median = 0.5, so both exposures are
  // log2(x / 0.5) with x = 2.11887 the ACES input that maps to 0.85. The reference maps to 0.85, the test
  // (1.05944 in) to (k0 x^2 + k1 x) / (k3 x^2 + k4 x + k5) = 0.690267; L* 93.8831 and 86.5173,
  // HyAB 7.36584, ^0.7 = 4.04628, so 0.95 / 16.5104 * 4.04628 = 0.232820.
  EXPECT_NEAR(flip_hdr(rgb(uniform(0.25f, 0.25f, 0.25f)), rgb(uniform(0.5f, 0.5f, 0.5f)), 8, 8).mean,
              0.232820, 1e-5);
}

// The HDR stop exposure takes the reference's median luminance as NVIDIA's FLIP C++ does: the sorted value
// at index n/2. On a two-level checkerboard (32 pixels at 0.5, 32 at 2) that is 2, the maximum, so the
// range is one exposure wide; the mean of the middle two (1.25) would stretch it by log2(2 / 1.25).
TEST(Flip, HdrMedianIsTheSortedValueAtHalf) {
  std::vector<float> board;
  for (int p = 0; p < 64; ++p) {
    const float v = (p % 8 + p / 8) % 2 ? 2.f : 0.5f;
    board.insert(board.end(), {v, v, v});
  }
  const FlipExposures e = flip_hdr_exposures(rgb(board));
  EXPECT_NEAR(e.start, std::log2(2.11887 / 2), 1e-5);
  EXPECT_DOUBLE_EQ(e.stop, e.start);
  EXPECT_EQ(e.count, 2);
  // Odd count: the middle value, the same either way (0.5 below it, 2 above).
  board.insert(board.end(), {1.f, 1.f, 1.f});
  EXPECT_NEAR(flip_hdr_exposures(rgb(board)).stop, std::log2(2.11887 / 1), 1e-5);
}

TEST(Flip, ErrorMapOnRequest) {
  const std::vector<float> ref = scene(), test = plus(ref, noise(ref.size(), 3), 0.2f);
  for (bool hdr : {false, true}) {
    FlipOptions o;
    EXPECT_TRUE((hdr ? flip_hdr : flip_ldr)(rgb(test), rgb(ref), W, H, o).map.empty());
    o.want_map = true;
    const FlipResult res = (hdr ? flip_hdr : flip_ldr)(rgb(test), rgb(ref), W, H, o);
    ASSERT_EQ(res.map.size(), size_t(W * H));
    double sum = 0;
    for (float v : res.map) {
      EXPECT_GE(v, 0.f);
      EXPECT_LE(v, 1.f);
      sum += v;
    }
    EXPECT_NEAR(sum / res.map.size(), res.mean, 1e-12);
    EXPECT_GT(res.mean, 0.0);
  }
  // The heat map: magma's ends.
  const std::vector<uint32_t> c = magma_rgba8({0.f, 1.f});
  EXPECT_EQ(c[0], 0xff040000u);   // (0.0015, 0.0005, 0.0139) * 255 = (0, 0, 4)
  EXPECT_EQ(c[1] & 0xffu, 252u);  // red of (0.987, 0.991, 0.750)
}

TEST(Flip, RejectsWhatItCannotCompare) {
  std::vector<float> v(8 * 8 * 2, 0.f);
  const Channels two{v.data(), 64, 2, 0, 2};
  EXPECT_THROW(flip_ldr(two, two, 8, 8), std::invalid_argument);
  const std::vector<float> a = uniform(0, 0, 0);
  EXPECT_THROW(flip_hdr(rgb(a), rgb(a), 8, 9), std::invalid_argument);
}

}  // namespace
}  // namespace haze::eval
