// The SVGF instance (denoise/svgf.hpp) on generated sequences with known answers: G-buffers and noisy
// demodulated inputs are made on the host, so each property is tested apart from the renderer.
// Thresholds were fixed before looking at results.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/packing.hpp>
#include <iostream>
#include <random>

#include "denoise/svgf.hpp"
#include "expect_error.hpp"
#include "render/renderer.hpp"
#include "shaders/glsl.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using denoise::SvgfParams;
using denoise::SvgfResult;

// A G-buffer pixel as the G-buffer pass writes it (shaders/common/gbuffer.glsl).
struct GPix {
  float depth = 0;
  glm::vec3 normal{0, 0, 1};
  glm::vec3 albedo{0.5f};
  uint32_t id = 0xffffffffu;
  glm::vec2 motion{0};
};

struct Frame {
  int W, H;
  std::vector<GPix> g;
  std::vector<glm::vec3> reference;  // demodulated
  explicit Frame(int w, int h) : W(w), H(h), g(size_t(w) * h), reference(size_t(w) * h) {}
  std::vector<float> gbuffer() const {
    std::vector<float> out(g.size() * glsl::G_STRIDE, 0.f);
    for (size_t p = 0; p < g.size(); ++p) {
      float* o = &out[p * glsl::G_STRIDE];
      o[glsl::G_DEPTH] = g[p].depth;
      glm::vec2 n = glsl::oct_encode(g[p].normal);
      o[glsl::G_NORMAL] = n.x;
      o[glsl::G_NORMAL + 1] = n.y;
      for (int c = 0; c < 3; ++c) o[glsl::G_ALBEDO + c] = g[p].albedo[c];
      o[glsl::G_INSTANCE] = glm::uintBitsToFloat(g[p].id);
      o[glsl::G_MOTION] = g[p].motion.x;
      o[glsl::G_MOTION + 1] = g[p].motion.y;
      o[glsl::G_PREV_DEPTH] = g[p].depth;
    }
    return out;
  }
  // What the denoiser should output: the reference remodulated.
  glm::vec3 expected(size_t p) const { return reference[p] * (g[p].depth > 0 ? g[p].albedo : glm::vec3(1)); }
};

// Runs one instance frame by frame on host-made inputs.
class Rig {
 public:
  Rig(int W, int H, const SvgfParams& p)
      : colour_(context(), "test colour", "test", size_t(W) * H * 12, "3 x f32"),
        g_(context(), "test g-buffer", "test", size_t(W) * H, render::kGBufferLayers),
        prev_(context(), "test previous g-buffer", "test", size_t(W) * H, render::kPrevGBufferLayers),
        svgf_(context(), "surface", p, W, H, true) {}
  SvgfResult run(const Frame& f, const std::vector<glm::vec3>& noisy) {
    colour_.upload(noisy);
    std::vector<float> g = f.gbuffer();
    if (first_) prev_.upload(g);
    first_ = false;
    g_.upload(g);
    denoise::SvgfInputs in{&colour_, 3, 0, &g_, &prev_, &g_[glsl::G_MOTION / 4], 4, glsl::G_MOTION % 4};
    in.epipole = epipole;
    context().submit_and_wait([&](VkCommandBuffer cmd) {
      svgf_.run(cmd, nullptr, in);
      gpu::compute_barrier(cmd);
      g_.copy_to(cmd, prev_);
    });
    return svgf_.download();
  }
  const denoise::Svgf& svgf() const { return svgf_; }
  std::optional<glm::vec3> epipole;  // the light's image, for an instance with an epipolar term

 private:
  gpu::Buffer colour_;
  gpu::PixelLayers g_, prev_;
  denoise::Svgf svgf_;
  bool first_ = true;
};

// Noisy estimate: the reference times a Gamma(k, 1/k) factor per pixel (mean 1, relative std 1/sqrt(k));
// k = 1 is exponential noise, like one path-traced sample.
std::vector<glm::vec3> noisy(const Frame& f, std::mt19937& rng, double k) {
  std::gamma_distribution<float> gamma(float(k), float(1.0 / k));
  std::vector<glm::vec3> out(f.reference.size());
  for (size_t p = 0; p < out.size(); ++p) out[p] = f.reference[p] * gamma(rng);
  return out;
}

double rel_mse(const Frame& f, const std::vector<glm::vec3>& x, bool remodulated) {
  double s = 0;
  for (size_t p = 0; p < x.size(); ++p) {
    glm::vec3 r = remodulated ? f.expected(p) : f.reference[p];
    for (int c = 0; c < 3; ++c) s += (x[p][c] - r[c]) * (x[p][c] - r[c]) / (r[c] * r[c] + 0.01);
  }
  return s / (3.0 * x.size());
}

// Two planes: a grey ramp on the left (instance 0, facing the camera at depth 2) and an orange wall on the
// right (instance 1, tilted, depth 4).
Frame two_planes(int W, int H, float level = 1.f) {
  Frame f(W, H);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      size_t p = size_t(y) * W + x;
      if (x < W / 2) {
        f.g[p] = {2.f, {0, 0, 1}, glm::vec3(0.5f), 0, {0, 0}};
        f.reference[p] = glm::vec3(0.2f + 0.6f * float(x) / W) * level;
      } else {
        f.g[p] = {4.f, glm::normalize(glm::vec3(0.6f, 0, 0.8f)), glm::vec3(0.5f), 1, {0, 0}};
        f.reference[p] = glm::vec3(0.8f, 0.4f, 0.2f) * level;
      }
    }
  return f;
}

SvgfParams mode(const std::string& m) {
  SvgfParams p;
  p.mode = m;
  return p;
}

TEST(Svgf, StaticSceneConvergesFarBelowTheInputError) {
  const int W = 64, H = 48;
  Frame f = two_planes(W, H);
  for (const char* m : {"adaptive", "classic", "adaptive, filtered feedback"}) {
    SvgfParams params = mode(std::string(m) == "classic" ? "classic" : "adaptive");
    if (std::string(m) == "adaptive, filtered feedback") params.feedback = "filtered";
    Rig rig(W, H, params);
    std::mt19937 rng(7);
    double input = 0, output = 0, mean_ratio = 0;
    double ref_mean = 0;
    for (size_t p = 0; p < f.reference.size(); ++p) ref_mean += glsl::luminance(f.expected(p));
    for (int t = 0; t < 64; ++t) {
      auto x = noisy(f, rng, 1.0);
      if (t == 63) input = rel_mse(f, x, false);
      SvgfResult r = rig.run(f, x);
      if (t == 63) output = rel_mse(f, r.colour, true);
      for (const glm::vec3& c : r.colour) ASSERT_TRUE(std::isfinite(c.x + c.y + c.z));
      // Energy: the denoised mean luminance over frames 16-63 against the reference's.
      double mean = 0;
      for (const glm::vec3& c : r.colour) mean += glsl::luminance(c);
      if (t >= 16) mean_ratio += mean / ref_mean / 48;
    }
    std::cout << m << ": relMSE of the 1-spp input " << input << ", after 64 frames " << output << " ("
              << input / output << "x lower); mean luminance over frames 16-63 / the reference's "
              << mean_ratio << "\n";
    // Measured 1512x (adaptive), 715x (classic) and 659x (adaptive with SVGF's feedback of the first filter
    // iteration, which feeds the filter's blur back into the history). Catches: the filtered feedback as
    // adaptive mode's default.
    EXPECT_LT(output, input / (std::string(m) == "adaptive" ? 1000 : 220)) << m;
    // Measured -0.9% (adaptive), -0.5% (filtered feedback) and -2.1% (classic: its gather normalization loses
    // energy on skewed noise, ClassicEnergyLossIsTheGatherNormalization; classic mode is Schied et al.'s by
    // definition and misses the 2% goal, docs/denoising.md).
    EXPECT_LT(std::abs(mean_ratio - 1), std::string(m) == "classic" ? 0.03 : 0.02) << m;
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Frames after a switch until the output's mean luminance is within 10% of the new reference's.
int frames_to_recover(Rig& rig, std::mt19937& rng, const Frame& f, double k, int max_frames = 40) {
  double ref = 0;
  for (size_t p = 0; p < f.reference.size(); ++p) ref += glsl::luminance(f.expected(p));
  for (int t = 1; t <= max_frames; ++t) {
    SvgfResult r = rig.run(f, noisy(f, rng, k));
    double mean = 0;
    for (const glm::vec3& c : r.colour) mean += glsl::luminance(c);
    if (std::abs(mean - ref) <= 0.1 * ref) return t;
  }
  return max_frames + 1;
}

TEST(Svgf, AdaptiveModeRecoversFromALightSwitchWithinFourFrames) {
  const int W = 64, H = 48;
  Frame dim = two_planes(W, H, 0.25f), bright = two_planes(W, H, 1.f);
  // Per-pixel relative noise 1/8 (k = 64) and 1/4 (k = 16).
  for (double k : {64.0, 16.0}) {
    int on[2], off[2];
    for (int i = 0; i < 2; ++i) {
      Rig rig(W, H, mode(i == 0 ? "adaptive" : "classic"));
      std::mt19937 rng(11);
      for (int t = 0; t < 32; ++t) rig.run(dim, noisy(dim, rng, k));
      on[i] = frames_to_recover(rig, rng, bright, k);
      for (int t = 0; t < 32; ++t) rig.run(bright, noisy(bright, rng, k));
      off[i] = frames_to_recover(rig, rng, dim, k);
    }
    std::cout << "noise k = " << k << ": light on: adaptive " << on[0] << " frames, classic " << on[1]
              << "; light off: adaptive " << off[0] << ", classic " << off[1] << "\n";
    EXPECT_LE(on[0], 4) << k;
    EXPECT_LE(off[0], 4) << k;
    // Classic mode blends with alpha = 0.2: from 0.25 to 1 the mean is within 10% once 0.75 * 0.8^n <= 0.1
    // (n = 10), from 1 to 0.25 once 0.75 * 0.8^n <= 0.025 (n = 16); measured exactly that at both noise
    // levels. Catches: a classic alpha of 0.25 (8 and 13 frames) or TAA lag added to it.
    EXPECT_NEAR(on[1], 10, 1) << k;
    EXPECT_NEAR(off[1], 16, 1) << k;
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(Svgf, FirefliesDoNotSpreadAndNonFiniteInputNeverReachesTheOutput) {
  const int W = 64, H = 48;
  Frame f = two_planes(W, H);
  const std::vector<glm::ivec2> fireflies = {{10, 10}, {40, 12}, {20, 30}, {50, 36}, {8, 40}};
  const std::vector<glm::ivec2> nans = {{30, 5}, {55, 20}}, infs = {{12, 22}, {45, 44}};
  for (const char* m : {"adaptive", "classic"}) {
    Rig rig(W, H, mode(m));
    std::mt19937 rng(3);
    for (int t = 0; t < 32; ++t) rig.run(f, noisy(f, rng, 4.0));
    auto x = noisy(f, rng, 4.0);
    auto at = [&](glm::ivec2 q) -> glm::vec3& { return x[size_t(q.y) * W + q.x]; };
    for (auto q : fireflies) at(q) = glm::vec3(1e6f);
    for (auto q : nans) at(q) = glm::vec3(std::nanf(""));
    for (auto q : infs) at(q) = glm::vec3(INFINITY, -INFINITY, INFINITY);
    SvgfResult r = rig.run(f, x);
    size_t bad = 0;
    for (size_t p = 0; p < r.colour.size(); ++p)
      bad += !std::isfinite(r.colour[p].x + r.colour[p].y + r.colour[p].z + r.variance[p] + r.history[p]);
    EXPECT_EQ(bad, 0u) << m;
    // Halo: the mean luminance of the 9x9 window around each firefly against the reference's.
    double worst = 0;
    for (auto q : fireflies) {
      double out = 0, ref = 0;
      for (int dy = -4; dy <= 4; ++dy)
        for (int dx = -4; dx <= 4; ++dx) {
          size_t p = size_t(q.y + dy) * W + (q.x + dx);
          out += glsl::luminance(r.colour[p]);
          ref += glsl::luminance(f.expected(p));
        }
      worst = std::max(worst, std::abs(out / ref - 1));
    }
    std::cout << m << ": worst relative error of a firefly's 9x9 neighbourhood " << worst << "\n";
    if (std::string(m) == "adaptive") {
      // Measured 0.0123 (0.0048 with SVGF's centre sigma and filtered feedback, the defaults before).
      EXPECT_LT(worst, 0.025);
    } else {
      // Classic mode has no firefly clamp: the 1e6 spreads (measured +291%), within 3x either way.
      EXPECT_GT(worst, 1.0);
      EXPECT_LT(worst, 9.0);
    }
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// A bright square moves right over a grey wall; where it was, the wall must come back without a trail.
TEST(Svgf, DisocclusionLeavesNoTrail) {
  const int W = 64, H = 48, speed = 2, side = 12;
  auto frame = [&](int t) {
    Frame f(W, H);
    int x0 = 4 + speed * t;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        size_t p = size_t(y) * W + x;
        bool square = x >= x0 && x < x0 + side && y >= 18 && y < 18 + side;
        if (square) {
          f.g[p] = {1.f, {0, 0, 1}, glm::vec3(0.8f), 1, {-float(speed), 0}};
          f.reference[p] = glm::vec3(1.0f, 0.1f, 0.1f);
        } else {
          f.g[p] = {5.f, {0, 0, 1}, glm::vec3(0.5f), 0, {0, 0}};
          f.reference[p] = glm::vec3(0.3f);
        }
      }
    return f;
  };
  Rig rig(W, H, mode("adaptive"));
  std::mt19937 rng(5);
  const int T = 16;
  Frame f = frame(0);
  SvgfResult r;
  for (int t = 0; t <= T; ++t) {
    f = frame(t);
    r = rig.run(f, noisy(f, rng, 16.0));
  }
  // Wall pixels the square left 3 to 8 frames ago.
  double worst_red = 0;
  int checked = 0;
  for (int y = 18; y < 30; ++y)
    for (int x = 4 + speed * (T - 8); x < 4 + speed * (T - 3); ++x) {
      size_t p = size_t(y) * W + x;
      ASSERT_EQ(f.g[p].id, 0u);
      worst_red = std::max(worst_red, double(r.colour[p].r - r.colour[p].g));
      ++checked;
    }
  std::cout << "largest red excess on uncovered wall " << worst_red << " (" << checked << " pixels)\n";
  EXPECT_GT(checked, 100);
  EXPECT_LT(worst_red, 0.01);  // the wall is grey (0.15 after remodulation); the square adds 0.72 red
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The camera pans: every pixel's previous position lies 3 px to its right, so the rightmost columns come
// from outside the image. Adaptive mode reuses the border's history (with its cap of 2), classic restarts.
TEST(Svgf, MotionLeavingTheScreenReusesTheBorder) {
  const int W = 48, H = 32;
  Frame f(W, H);
  for (size_t p = 0; p < f.g.size(); ++p) {
    f.g[p] = {2.f, {0, 0, 1}, glm::vec3(0.5f), 0, {3.f, 0.f}};
    f.reference[p] = glm::vec3(0.6f);
  }
  for (const char* m : {"adaptive", "classic"}) {
    Rig rig(W, H, mode(m));
    std::mt19937 rng(9);
    SvgfResult r;
    for (int t = 0; t < 8; ++t) r = rig.run(f, noisy(f, rng, 16.0));
    double edge = 0, inner = 0;
    for (int y = 0; y < H; ++y) {
      edge += r.history[size_t(y) * W + (W - 1)] / H;
      inner += r.history[size_t(y) * W + W / 4] / H;
    }
    std::cout << m << ": history length at the entering edge " << edge << ", inside " << inner << "\n";
    const double expected_edge = std::string(m) == "adaptive" ? 2.0 : 1.0;
    EXPECT_NEAR(edge, expected_edge, 1e-3);
    // Adaptive mode's history is the unfiltered accumulation (feedback "accumulated"): on this noise the
    // percentile cap cuts a few inner pixels' histories (measured 7.80; exactly 8 with adapt_strength 0 or
    // feedback "filtered").
    if (std::string(m) == "adaptive") {
      EXPECT_GT(inner, 7.4);
      EXPECT_LE(inner, 8.0 + 1e-3);
    } else {
      EXPECT_NEAR(inner, 8.0, 1e-3);
    }
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The percentiles pass against a sort on the CPU: per 8x8 block the interpolated quantiles of the pixels'
// luminances and of the 2x2 quad means, on an image whose last blocks are cut in both directions (37x21),
// with ties, negative and non-finite inputs (both count as luminance 0). Seen to fail when the bitonic sort's
// last merge (k = 64) was left out (each block's two sorted halves: 30 of the 15 blocks' 60 values wrong, the
// firefly pair of every block) and when the cut blocks ranked all 64 slots (n = 64, the +inf padding among
// the ranks: 14 wrong, the firefly pair of the 7 cut blocks).
TEST(Svgf, PercentilesMatchASortOnTheCpu) {
  const int W = 37, H = 21, BX = (W + 7) / 8, BY = (H + 7) / 8;
  Frame f = two_planes(W, H);
  std::mt19937 rng(13);
  std::exponential_distribution<float> expo(1.f);
  std::vector<glm::vec3> in(size_t(W) * H);
  for (size_t p = 0; p < in.size(); ++p) {
    in[p] = glm::vec3{expo(rng), expo(rng), expo(rng)};
    if (p % 7 == 0) in[p] = glm::round(in[p] * 2.f) * 0.5f;  // ties
  }
  in[3] = glm::vec3(NAN, 1.f, 1.f);
  in[50] = glm::vec3(INFINITY, 0.f, 0.f);
  in[W * 9 + 33] = glm::vec3(-2.f, 0.1f, 0.f);
  SvgfParams params;
  params.firefly_low = 0.25f;
  params.firefly_up = 0.9f;
  params.adapt_low = 0.19f;
  params.adapt_up = 0.907f;
  Rig rig(W, H, params);
  rig.run(f, in);
  std::vector<glm::vec4> gpu = rig.svgf().percentiles().download_vector<glm::vec4>();
  ASSERT_GE(gpu.size(), size_t(BX * BY));
  auto lum = [&](int x, int y) {
    glm::vec3 c = in[size_t(y) * W + x];
    float l = glm::dot(c, glm::vec3(0.2126f, 0.7152f, 0.0722f));
    return std::isfinite(c.x) && std::isfinite(c.y) && std::isfinite(c.z) && std::isfinite(l)
               ? std::max(l, 0.f)
               : 0.f;
  };
  auto quantile = [](std::vector<float> v, float q) {
    std::sort(v.begin(), v.end());
    float x = q * float(v.size() - 1);
    size_t i = size_t(x), j = std::min(i + 1, v.size() - 1);
    return v[i] + (v[j] - v[i]) * (x - float(i));
  };
  int wrong = 0;
  for (int by = 0; by < BY; ++by)
    for (int bx = 0; bx < BX; ++bx) {
      std::vector<float> pixels, quads;
      for (int y = by * 8; y < std::min(by * 8 + 8, H); ++y)
        for (int x = bx * 8; x < std::min(bx * 8 + 8, W); ++x) pixels.push_back(lum(x, y));
      for (int qy = by * 8; qy < std::min(by * 8 + 8, H); qy += 2)
        for (int qx = bx * 8; qx < std::min(bx * 8 + 8, W); qx += 2) {
          float sum = 0.f, m = 0.f;
          for (int k = 0; k < 4; ++k) {
            int x = qx + (k & 1), y = qy + (k >> 1);
            if (x < std::min(bx * 8 + 8, W) && y < std::min(by * 8 + 8, H)) sum += lum(x, y), m += 1.f;
          }
          quads.push_back(sum / m);
        }
      const glm::vec4 cpu(quantile(pixels, params.firefly_low), quantile(pixels, params.firefly_up),
                          quantile(quads, params.adapt_low), quantile(quads, params.adapt_up));
      const glm::vec4 g = gpu[size_t(by) * BX + bx];
      for (int c = 0; c < 4; ++c) {
        // Float rounding of the luminance and the quad means only (measured: at most 7.3e-8 here).
        const bool ok = std::abs(g[c] - cpu[c]) <= 2.5e-7f * (1.f + std::abs(cpu[c]));
        wrong += !ok;
        EXPECT_TRUE(ok) << "block " << bx << "," << by << " value " << c << ": gpu " << g[c] << " cpu "
                        << cpu[c];
      }
    }
  EXPECT_EQ(wrong, 0);
}

// Each percentile-driven mechanism changes the output when switched off: the firefly clamp (firefly_bias
// so large that only the hard clamp firefly_max is left), the adaptive history cap (adapt_strength 0) and
// border reuse (border_history 1).
TEST(Svgf, EachPercentileMechanismMattersWhenSwitchedOff) {
  const int W = 64, H = 48;
  {
    Frame f = two_planes(W, H);
    auto halo = [&](const SvgfParams& p) {
      Rig rig(W, H, p);
      std::mt19937 rng(3);
      for (int t = 0; t < 32; ++t) rig.run(f, noisy(f, rng, 4.0));
      auto x = noisy(f, rng, 4.0);
      x[size_t(20) * W + 20] = glm::vec3(1e6f);
      SvgfResult r = rig.run(f, x);
      double out = 0, ref = 0;
      for (int dy = -4; dy <= 4; ++dy)
        for (int dx = -4; dx <= 4; ++dx) {
          size_t q = size_t(20 + dy) * W + (20 + dx);
          out += glsl::luminance(r.colour[q]);
          ref += glsl::luminance(f.expected(q));
        }
      return std::abs(out / ref - 1);
    };
    SvgfParams off;
    off.firefly_bias = 1e30f;
    const double on_err = halo(SvgfParams{}), off_err = halo(off);
    std::cout << "firefly halo: clamp on " << on_err << ", off " << off_err << "\n";
    // Measured 0.00011 on, 7.4 off (0.0054 and 0.10 with SVGF's centre sigma and filtered feedback: the
    // pair's sigma lets the unclamped firefly's neighbours take it in).
    EXPECT_GT(off_err, 6 * on_err);
  }
  {
    Frame dim = two_planes(W, H, 0.25f), bright = two_planes(W, H, 1.f);
    auto recover = [&](const SvgfParams& p) {
      Rig rig(W, H, p);
      std::mt19937 rng(11);
      for (int t = 0; t < 32; ++t) rig.run(dim, noisy(dim, rng, 16.0));
      return frames_to_recover(rig, rng, bright, 16.0);
    };
    SvgfParams off;
    off.adapt_strength = 0;
    const int on_frames = recover(SvgfParams{}), off_frames = recover(off);
    std::cout << "light on: frames to recover with adaptivity " << on_frames << ", without " << off_frames
              << "\n";
    EXPECT_GT(off_frames, 3 * on_frames);  // measured 3, and not within 40 frames without
  }
  {
    Frame f(W, H);
    for (size_t p = 0; p < f.g.size(); ++p) {
      f.g[p] = {2.f, {0, 0, 1}, glm::vec3(0.5f), 0, {3.f, 0.f}};
      f.reference[p] = glm::vec3(0.6f);
    }
    auto edge = [&](const SvgfParams& p) {
      Rig rig(W, H, p);
      std::mt19937 rng(9);
      SvgfResult r;
      for (int t = 0; t < 8; ++t) r = rig.run(f, noisy(f, rng, 16.0));
      double h = 0;
      for (int y = 0; y < H; ++y) h += r.history[size_t(y) * W + (W - 1)] / H;
      return std::make_pair(h, r.colour);
    };
    SvgfParams off;
    off.border_history = 1;
    const auto [h_on, c_on] = edge(SvgfParams{});
    const auto [h_off, c_off] = edge(off);
    double diff = 0;
    for (int y = 0; y < H; ++y)
      diff += glm::length(c_on[size_t(y) * W + W - 1] - c_off[size_t(y) * W + W - 1]);
    std::cout << "border: history at the entering edge with reuse " << h_on << ", without " << h_off
              << "; mean colour change there " << diff / H << "\n";
    EXPECT_NEAR(h_on, 2.0, 1e-3);
    EXPECT_NEAR(h_off, 1.0, 1e-3);
    EXPECT_GT(diff / H, 2e-3);  // measured 0.0054
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Where classic mode's energy goes on the static sequence (-2.1% over frames 16-63, against the 2% goal):
// the filter's gather normalization. With skewed noise, a luminance edge-stopping term keeps dark centres
// from their bright neighbours more than the reverse, and dividing by each centre's own weights then loses
// energy; without filter iterations classic mode keeps the mean, and adaptive mode's energy-conserving splat
// normalization removes the loss. Classic mode stays Schied et al.'s gather by definition; its loss is larger
// than adaptive mode's (-1.0%) because alpha = 0.2 averages about 9 frames where adaptive mode averages up to
// 32, so its input stays more skewed. Catches: a splat pass that does not divide by the weight sums.
TEST(Svgf, ClassicEnergyLossIsTheGatherNormalization) {
  const int W = 64, H = 48;
  Frame f = two_planes(W, H);
  double ref_mean = 0;
  for (size_t p = 0; p < f.reference.size(); ++p) ref_mean += glsl::luminance(f.expected(p));
  auto mean_ratio = [&](const SvgfParams& p) {
    Rig rig(W, H, p);
    std::mt19937 rng(7);
    double m = 0;
    for (int t = 0; t < 64; ++t) {
      SvgfResult r = rig.run(f, noisy(f, rng, 1.0));
      double mean = 0;
      for (const glm::vec3& c : r.colour) mean += glsl::luminance(c);
      if (t >= 16) m += mean / ref_mean / 48;
    }
    return m - 1;
  };
  SvgfParams classic = mode("classic"), unfiltered = mode("classic"), splat, gather;
  unfiltered.iterations = 0;
  splat.normalization = "splat";
  gather.normalization = "gather";
  // Classic mode feeds the first iteration's output back, so the adaptive runs do too: with the accumulated
  // feedback (the default) both normalizations lose about 0.9%, to the percentile cap cutting noisy
  // histories (-0.2% with adapt_strength 0), which would hide the normalization's own share.
  splat.feedback = gather.feedback = "filtered";
  gather.luminance_sigma = splat.luminance_sigma = "centre";
  const double e_classic = mean_ratio(classic), e_unfiltered = mean_ratio(unfiltered);
  const double e_gather = mean_ratio(gather), e_splat = mean_ratio(splat);
  std::cout << "mean luminance error over frames 16-63: classic " << e_classic << ", classic without filter "
            << e_unfiltered << "; adaptive gather " << e_gather << ", adaptive splat " << e_splat << "\n";
  EXPECT_LT(e_classic, -0.007);  // measured -2.1%
  EXPECT_GT(e_classic, -0.063);
  EXPECT_LT(std::abs(e_unfiltered), 0.005);
  EXPECT_LT(e_gather, -0.003);  // measured -1.0%
  EXPECT_LT(std::abs(e_splat), 0.003);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The splat normalization conserves the signal's sum exactly (to half-float rounding), on sparse noise where
// gather loses a large share: one frame of 5% bright pixels over two planes, firefly clamp off. Catches:
// weights that are not symmetric, or a pass that does not divide by the weight sums.
TEST(Svgf, SplatNormalizationConservesTheSum) {
  const int W = 64, H = 48;
  Frame f = two_planes(W, H);
  std::mt19937 rng(13);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<glm::vec3> x(f.reference.size());
  double in = 0;
  for (size_t p = 0; p < x.size(); ++p) {
    x[p] = u(rng) < 0.05f ? f.reference[p] * 20.f : glm::vec3(0.f);
    in += glsl::luminance(x[p]) * 0.5;  // remodulated by the planes' albedo 0.5
  }
  auto sum_of = [&](const std::string& normalization, const std::string& kernel, float epipolar = 0.f) {
    SvgfParams p;
    p.normalization = normalization;
    p.kernel = kernel;
    p.firefly_bias = 1e30f;
    p.epipolar = epipolar;
    Rig rig(W, H, p);
    rig.epipole = glm::vec3(0.5f * W, -float(H), 1.f);
    SvgfResult r = rig.run(f, x);
    double out = 0;
    for (const glm::vec3& c : r.colour) out += glsl::luminance(c);
    return out / in - 1;
  };
  for (const char* kernel : {"5x5", "subsampled"}) {
    const double splat = sum_of("splat", kernel), gather = sum_of("gather", kernel);
    std::cout << kernel << ": output sum / input sum - 1: splat " << splat << ", gather " << gather << "\n";
    EXPECT_LT(std::abs(splat), 1e-4) << kernel;  // measured 1.7e-5 (5x5) and 1.2e-7 (subsampled)
    EXPECT_LT(gather, -0.12) << kernel;          // measured -46% and -25% (luminance_sigma pair)
  }
  // The epipolar term's weight is symmetric too (the line's normal at each end of a pair).
  const double epipolar = sum_of("splat", "5x5", 1.f);
  std::cout << "5x5 with the epipolar term: output sum / input sum - 1: splat " << epipolar << "\n";
  EXPECT_LT(std::abs(epipolar), 1e-4);  // measured 1.1e-5
  EXPECT_EQ(context().validation_messages(), 0u);
}

// light_epipole() against glm's own camera matrices (lookAt, perspective): a point light's image is its
// projected position; a sun's is the point where the images of all lines along its direction meet, so every
// such line's image passes through it; with no such light, or two, there is none.
TEST(Svgf, LightEpipoleIsTheLightsImage) {
  nlohmann::json j = {{"camera", {{"position", {1.0, 2.0, 5.0}}, {"target", {0.0, 1.0, 0.0}}, {"fov_y", 50}}},
                      {"render", {{"width", 160}, {"height", 90}}},
                      {"lights", {{"points", {{{"position", {0.5, 1.5, 0.0}}}}}}}};
  const glm::mat4 view = glm::lookAt(glm::vec3(1, 2, 5), glm::vec3(0, 1, 0), glm::vec3(0, 1, 0));
  const glm::mat4 proj = glm::perspective(glm::radians(50.f), 160.f / 90.f, 0.1f, 100.f);
  auto pixel = [&](glm::vec3 x) {
    const glm::vec4 c = proj * view * glm::vec4(x, 1);
    return glm::vec2((c.x / c.w + 1) * 0.5f * 160.f, (1 - c.y / c.w) * 0.5f * 90.f);
  };
  auto image = [](const std::optional<glm::vec3>& e) { return glm::vec2(e->x, e->y) / e->z; };
  const std::optional<glm::vec3> point = render::light_epipole(make_scene(j));
  ASSERT_TRUE(point.has_value());
  EXPECT_LT(glm::length(image(point) - pixel({0.5f, 1.5f, 0.f})), 1e-3f);

  j["lights"] = {{"sun", {{"direction", {-0.35, 0.55, -1.0}}}}};
  const std::optional<glm::vec3> sun = render::light_epipole(make_scene(j));
  ASSERT_TRUE(sun.has_value());
  const glm::vec3 L = glm::normalize(glm::vec3(-0.35f, 0.55f, -1.f));
  for (const glm::vec3 x : {glm::vec3(0, 0, 0), glm::vec3(-1, 0.5f, 1), glm::vec3(2, 0, -1)}) {
    const glm::vec2 a = pixel(x), b = pixel(x + 0.5f * L);
    const glm::vec2 to_e = glm::vec2(sun->x, sun->y) - a * sun->z;  // towards the image, in homogeneous form
    const float sine = (b - a).x * to_e.y - (b - a).y * to_e.x;
    EXPECT_LT(std::abs(sine) / (glm::length(b - a) * glm::length(to_e)), 1e-4f);
  }
  EXPECT_LT(glm::length(image(sun) - pixel(glm::vec3(1, 2, 5) + 100.f * L)), 1e-2f);

  j["lights"]["points"] = {{{"position", {0.5, 1.5, 0.0}}}};
  EXPECT_FALSE(render::light_epipole(make_scene(j)).has_value());
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  EXPECT_FALSE(render::light_epipole(make_scene(j)).has_value());
}

// The epipolar term (epipolar > 0): sheets of light are lines through the light's image, and the filter keeps
// them when it smooths along those lines. One frame of stripes radiating from a light above the image (3.5
// pixels wide at the centre, Gamma(4) noise: 4 samples), the filter with the term (width 1 pixel), without
// it, and with a wrong light image (a direction along x, whose lines cross the stripes). The stripes'
// contrast (the mean inside the bright stripes over the mean inside the dark ones, pixels 1 away from a
// stripe edge) against the reference's. Catches: the term off, or the line's normal taken as its direction.
TEST(Svgf, EpipolarTermKeepsSheetsAlongTheLightsLines) {
  const int W = 64, H = 48;
  Frame f = two_planes(W, H);
  const glm::vec2 e(0.5f * W, -float(H));
  const float step = 3.5f / glm::length(glm::vec2(0.5f * W, 0.5f * H) - e);  // radians per stripe
  std::vector<int> stripe(f.reference.size());
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const glm::vec2 d = glm::vec2(x + 0.5f, y + 0.5f) - e;
      stripe[size_t(y) * W + x] = int(std::floor(std::atan2(d.x, d.y) / step));
    }
  for (size_t p = 0; p < f.reference.size(); ++p) f.reference[p] = glm::vec3(stripe[p] % 2 ? 1.f : 0.2f);
  // Pixels whose 3x3 neighbourhood lies in one stripe.
  auto interior = [&](int x, int y) {
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        const int qx = std::clamp(x + dx, 0, W - 1), qy = std::clamp(y + dy, 0, H - 1);
        if (stripe[size_t(qy) * W + qx] != stripe[size_t(y) * W + x]) return false;
      }
    return true;
  };
  auto contrast = [&](const std::vector<glm::vec3>& img, bool remodulated) {
    double s[2] = {0, 0}, n[2] = {0, 0};
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const size_t p = size_t(y) * W + x;
        if (!interior(x, y)) continue;
        const int b = stripe[p] % 2 ? 1 : 0;
        s[b] += glsl::luminance(img[p]) / (remodulated ? 0.5 : 1.0);
        n[b] += 1;
      }
    return (s[1] / n[1]) / (s[0] / n[0]);
  };
  const double truth = contrast(f.reference, false);
  std::mt19937 rng(29);
  const std::vector<glm::vec3> x = noisy(f, rng, 4.0);
  auto run = [&](float width, std::optional<glm::vec3> epipole) {
    SvgfParams p;
    p.epipolar = width;
    Rig rig(W, H, p);
    rig.epipole = epipole;
    return contrast(rig.run(f, x).colour, true) / truth - 1;
  };
  const double along = run(1.f, glm::vec3(e, 1.f)), flat = run(0.f, std::nullopt),
               across = run(1.f, glm::vec3(1.f, 0.f, 0.f));
  std::cout << "stripes' contrast / reference's - 1: epipolar term " << along << ", without " << flat
            << ", lines across the stripes " << across << " (noisy input " << contrast(x, false) / truth - 1
            << ")\n";
  // Measured -13%, -49% and -62%.
  EXPECT_GT(along, -0.25);
  EXPECT_GT(along - flat, 0.2);
  EXPECT_LT(across, flat - 0.05);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The volume instance's own geometry (geometry "virtual_points", geometry.comp) against the same on the CPU:
// the 3x3 median of the valid virtual point depths and, per axis, the one-sided difference of smaller
// magnitude. A step between two depths with 10% of the pixels replaced by outliers; on the first frame the
// accumulated depth is the median itself. Catches: the 3x3 mean instead of the median (outliers then leak
// into every neighbour).
TEST(Svgf, VirtualPointGeometryIsTheMedianDepthAndItsGradient) {
  const int W = 32, H = 24;
  const size_t pixels = size_t(W) * H;
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<float> depth(pixels);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      depth[size_t(y) * W + x] =
          u(rng) < 0.1f ? 1.f + 9.f * u(rng) : (x < W / 2 ? 3.f : 6.f + 0.05f * float(y));
  depth[5] = 0.f;  // no virtual point
  std::vector<float> median(pixels, 0.f);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      if (depth[size_t(y) * W + x] <= 0.f) continue;
      std::vector<float> v;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int qx = x + dx, qy = y + dy;
          if (qx < 0 || qy < 0 || qx >= W || qy >= H) continue;
          const float d = depth[size_t(qy) * W + qx];
          if (d > 0.f) v.push_back(d);
        }
      std::sort(v.begin(), v.end());
      median[size_t(y) * W + x] =
          v.size() % 2 ? v[v.size() / 2] : 0.5f * (v[v.size() / 2 - 1] + v[v.size() / 2]);
    }
  auto at = [&](int x, int y) {
    return x < 0 || y < 0 || x >= W || y >= H ? 0.f : median[size_t(y) * W + x];
  };
  auto one_sided = [](float z, float minus, float plus) {
    if (minus <= 0 && plus <= 0) return 0.f;
    if (minus <= 0) return plus - z;
    if (plus <= 0) return z - minus;
    return std::abs(plus - z) < std::abs(z - minus) ? plus - z : z - minus;
  };

  SvgfParams p = denoise::volume_defaults();
  denoise::Svgf svgf(context(), "volume", p, W, H, false);
  gpu::Buffer colour(context(), "test colour", "test", pixels * 12, "3 x f32");
  gpu::Buffer motion(context(), "test motion", "test", pixels * 8, "2 x f32");
  gpu::Buffer vp(context(), "test depth", "test", pixels * 4, "f32");
  colour.upload(std::vector<float>(pixels * 3, 0.5f));
  motion.fill_zero();
  vp.upload(depth);
  denoise::SvgfInputs in;
  in.colour = &colour;
  in.motion = &motion;
  in.depth = &vp;
  in.epipole = glm::vec3(0.5f * W, -2.f * H, 1.f);  // a light above the image (the default epipolar term)
  context().submit_and_wait([&](VkCommandBuffer cmd) { svgf.run(cmd, nullptr, in); });
  ASSERT_NE(svgf.geometry_depth(), nullptr);
  const std::vector<glm::uvec2> geo = svgf.geometry_depth()->download_vector<glm::uvec2>();
  double worst_z = 0, worst_g = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const size_t q = size_t(y) * W + x;
      const float z = glm::uintBitsToFloat(geo[q].x);
      const glm::vec2 g = glm::unpackHalf2x16(geo[q].y);
      const float zc = median[q];
      worst_z = std::max(worst_z, double(std::abs(z - zc)) / std::max(zc, 1e-3f));
      if (zc <= 0) continue;
      const glm::vec2 gc(one_sided(zc, at(x - 1, y), at(x + 1, y)),
                         one_sided(zc, at(x, y - 1), at(x, y + 1)));
      worst_g = std::max(worst_g, double(glm::length(g - gc)) / (1e-3 + glm::length(gc)));
    }
  std::cout << "geometry against the CPU: worst relative depth difference " << worst_z << ", gradient "
            << worst_g << "\n";
  EXPECT_LT(worst_z, 1e-6);    // the same float operations up to (Y z) / Y
  EXPECT_LT(worst_g, 1.2e-3);  // half floats: measured 4.0e-4
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The instance against its own symmetry: the input mirrored in x (or y) gives the output mirrored, both
// kernels, three frames. A scene of depth steps, tilted normals and gamma noise, 40x32. Every pass is
// mirror-symmetric up to float rounding (the mirrored pixel visits its taps in the mirrored order), so a tap
// at the wrong offset or a pixel written from another's sums breaks it; this guards the indexing that
// several pixels per invocation would change (docs/denoising.md, Performance). Rounding alone leaves the
// worst pixel within 6e-4 (measured below). Catches: one diagonal tap of the subsampled kernel a row off
// (ivec2(-1, 2) for ivec2(-1, 1) in filter.comp: worst 5.0, mean 0.15) and the TAA's 3x3 box without its
// right column (mirrored in x: worst 0.41, mean 0.013).
// The pixel that (x, y) mirrors, in x or in y.
size_t denoise_mirror_index(int x, int y, int W, int H, bool x_axis) {
  return x_axis ? size_t(y) * W + (W - 1 - x) : size_t(H - 1 - y) * W + x;
}

std::vector<glm::vec3> denoise_mirror(const std::vector<glm::vec3>& v, int W, int H, bool x_axis) {
  std::vector<glm::vec3> out(v.size());
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) out[size_t(y) * W + x] = v[denoise_mirror_index(x, y, W, H, x_axis)];
  return out;
}

Frame denoise_mirror(const Frame& f, bool x_axis) {
  Frame m(f.W, f.H);
  m.reference = denoise_mirror(f.reference, f.W, f.H, x_axis);
  for (int y = 0; y < f.H; ++y)
    for (int x = 0; x < f.W; ++x) {
      GPix g = f.g[denoise_mirror_index(x, y, f.W, f.H, x_axis)];
      g.normal[x_axis ? 0 : 1] *= -1.f;
      m.g[size_t(y) * f.W + x] = g;
    }
  return m;
}

TEST(Svgf, MirroredInputGivesTheMirroredOutput) {
  const int W = 40, H = 32;
  Frame f(W, H);
  std::mt19937 rng(21);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const size_t p = size_t(y) * W + x;
      const int region = (x / 7 + 2 * (y / 5)) % 4;
      f.g[p] = {2.f + float(region) + 0.02f * float(x + y),
                glm::normalize(glm::vec3(0.3f * float(region - 1), 0.2f * float(region % 2), 1.f)),
                glm::vec3(0.5f),
                uint32_t(region),
                {0, 0}};
      f.reference[p] = glm::vec3(0.2f + 0.8f * u(rng), 0.3f + 0.2f * float(region), 0.5f);
    }
  std::vector<std::vector<glm::vec3>> inputs;
  for (int t = 0; t < 3; ++t) inputs.push_back(noisy(f, rng, 2.0));
  for (const char* kernel : {"5x5", "subsampled"})
    for (bool x_axis : {true, false}) {
      SvgfParams p;
      p.kernel = kernel;
      Rig a(W, H, p), b(W, H, p);
      const Frame fm = denoise_mirror(f, x_axis);
      double worst = 0, sum = 0;
      for (int t = 0; t < 3; ++t) {
        const SvgfResult ra = a.run(f, inputs[t]);
        const std::vector<glm::vec3> rb =
            denoise_mirror(b.run(fm, denoise_mirror(inputs[t], W, H, x_axis)).colour, W, H, x_axis);
        for (size_t q = 0; q < rb.size(); ++q)
          for (int c = 0; c < 3; ++c) {
            const double d = std::abs(ra.colour[q][c] - rb[q][c]) / (std::abs(ra.colour[q][c]) + 1e-2);
            worst = std::max(worst, d);
            sum += d / (3.0 * rb.size() * 3);
          }
      }
      std::cout << kernel << (x_axis ? ", mirrored in x" : ", mirrored in y")
                << ": output against the mirrored output's mirror, worst relative difference " << worst
                << ", mean " << sum << "\n";
      // Measured: worst 5.7e-4, mean 2.8e-7 (5x5 mirrored in y); the subsampled kernel in x is exact.
      EXPECT_LT(worst, 1.5e-3) << kernel << (x_axis ? " x" : " y");
      EXPECT_LT(sum, 1e-6) << kernel << (x_axis ? " x" : " y");
    }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The history test may judge the previous output instead of the history only where both are in the same
// units: a remodulating instance's output carries the albedo (and emission) that its history does not.
TEST(Svgf, OutputWitnessNeedsAnInstanceThatDoesNotRemodulate) {
  SvgfParams p;
  p.history_test = 1.f;
  p.history_witness = "output";
  try {
    denoise::Svgf svgf(context(), "surface", p, 16, 16, true);
    ADD_FAILURE() << "no error for a remodulating instance";
  } catch (const gpu::Error& e) {
    EXPECT_NE(std::string(e.what()).find("svgf.surface: history_witness \"output\" needs an instance that "
                                         "does not remodulate"),
              std::string::npos)
        << e.what();
  }
  EXPECT_NO_THROW(denoise::Svgf(context(), "volume", denoise::volume_defaults(), 16, 16, false));
  read_error({{"denoise", {{"surface", {{"history_witness", "output"}}}}}},
             {"scene.json: denoise.surface.history_witness", "only \"history\" is valid"});
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(Svgf, MemoryAt1080pIsWithinBudget) {
  auto before = context().ledger().per_category();
  denoise::Svgf svgf(context(), "surface", SvgfParams{}, 1920, 1080, true);
  auto cat = context().ledger().per_category();
  uint64_t temps = cat["svgf.surface per-frame temporaries"] - before["svgf.surface per-frame temporaries"];
  uint64_t prev = cat["svgf.surface previous-frame data"] - before["svgf.surface previous-frame data"];
  std::cout << "1920x1080: temporaries " << temps / 1e6 << " MB, previous-frame data " << prev / 1e6
            << " MB\n";
  // 33.7 MB plus the taps' packed geometry (16.6 MB); the seed's reference used about 67 MB.
  EXPECT_LE(temps, 51'000'000u);
  EXPECT_LE(prev, 60'000'000u);
}

}  // namespace
}  // namespace haze::test
