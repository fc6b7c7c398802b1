// The shared sampling routines (shaders/common/sampling.glsl compiled as C++): normalisation, moments and
// chi-square goodness of fit. Significance fixed up front: alpha = 1e-4 per test.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include "shaders/glsl.hpp"

namespace {

using namespace haze::glsl;

// Chi-square critical value at alpha = 1e-4 (Wilson-Hilferty; z = 3.719).
double chi2_critical(int df) {
  double a = 2.0 / (9.0 * df);
  double t = 1 - a + 3.719 * std::sqrt(a);
  return df * t * t * t;
}

double simpson(const std::function<double(double)>& f, double a, double b, int n = 2000) {
  double h = (b - a) / n, s = f(a) + f(b);
  for (int i = 1; i < n; ++i) s += f(a + i * h) * (i % 2 ? 4 : 2);
  return s * h / 3;
}

// Bins samples of x in [a, b] and compares with the integral of pdf over each bin.
double chi2_statistic(const std::vector<double>& xs, double a, double b, int bins,
                      const std::function<double(double)>& pdf, int* df, double total = 0) {
  if (total == 0) total = double(xs.size());
  std::vector<double> counts(bins, 0.0);
  for (double x : xs) counts[std::min(bins - 1, std::max(0, int((x - a) / (b - a) * bins)))] += 1;
  double chi2 = 0;
  *df = -1;
  double pooled_obs = 0, pooled_exp = 0;
  for (int i = 0; i < bins; ++i) {
    double lo = a + (b - a) * i / bins, hi = a + (b - a) * (i + 1) / bins;
    double expected = simpson(pdf, lo, hi, 200) * total;
    // Pool sparse bins so that every cell expects at least 5 samples.
    pooled_obs += counts[i];
    pooled_exp += expected;
    if (pooled_exp >= 5 || i == bins - 1) {
      chi2 += (pooled_obs - pooled_exp) * (pooled_obs - pooled_exp) / std::max(pooled_exp, 1e-12);
      ++*df;
      pooled_obs = pooled_exp = 0;
    }
  }
  return chi2;
}

class HG : public ::testing::TestWithParam<float> {};

TEST_P(HG, IsNormalisedWithMeanCosineG) {
  float g = GetParam();
  // Fine steps: at g = 0.99 the lobe is about 1e-4 wide in mu.
  double norm = simpson([&](double mu) { return 2 * M_PI * hg_phase(float(mu), g); }, -1, 1, 2000000);
  double mean = simpson([&](double mu) { return 2 * M_PI * mu * hg_phase(float(mu), g); }, -1, 1, 2000000);
  EXPECT_NEAR(norm, 1.0, 2e-3);
  EXPECT_NEAR(mean, g, 2e-3);
}

TEST_P(HG, SampledDirectionsFollowThePhaseFunction) {
  float g = GetParam();
  uint state = rng_init(17u, 3u, uint(g * 1000 + 5000));
  // 1 - mu of each direction, in double from |w - axis|^2 / 2: a float dot product resolves mu only to 6e-8
  // near 1, where the lobe of g = 0.99 keeps a tenth of its samples within 1e-5. 10^6 samples: the sampler's
  // former mu = (1 + g^2 - s^2) / 2g, which cancels there, gives a chi-square of 321 at g = 0.99 (105 now).
  std::vector<double> one_minus_mus;
  vec3 axis = normalize(vec3(0.3f, -0.5f, 0.8f));
  for (int i = 0; i < 1000000; ++i) {
    const float u1 = rng_next(state), u2 = rng_next(state);  // in this order, as GLSL evaluates arguments
    vec3 w = hg_sample(axis, g, vec2(u1, u2));
    ASSERT_NEAR(length(w), 1.0f, 1e-4f);
    const double dx = double(w.x) - axis.x, dy = double(w.y) - axis.y, dz = double(w.z) - axis.z;
    one_minus_mus.push_back(0.5 * (dx * dx + dy * dy + dz * dz));
  }
  // Bins equal in probability (from the closed-form CDF, written in 1 - mu) resolve the forward lobe at any
  // g.
  auto cdf_one_minus = [&](double om) {
    if (std::abs(g) < 1e-3f) return 1 - 0.5 * om;
    double gg = g;
    return (1 - gg * gg) / (2 * gg) * (1 / std::sqrt((1 - gg) * (1 - gg) + 2 * gg * om) - 1 / (1 + gg));
  };
  auto cdf = [&](double mu) { return cdf_one_minus(1 - mu); };
  const int bins = 100;
  std::vector<double> counts(bins, 0.0);
  for (double om : one_minus_mus) counts[std::clamp(int(cdf_one_minus(om) * bins), 0, bins - 1)] += 1;
  double chi2 = 0, expected = double(one_minus_mus.size()) / bins;
  for (double c : counts) chi2 += (c - expected) * (c - expected) / expected;
  int df = bins - 1;
  // The CDF itself must match the phase function it claims to integrate.
  EXPECT_NEAR(cdf(1.0), 1.0, 1e-6);
  EXPECT_NEAR(cdf(0.3) - cdf(0.2),
              simpson([&](double mu) { return 2 * M_PI * hg_phase(float(mu), g); }, 0.2, 0.3, 20000), 1e-4);
  EXPECT_LT(chi2, chi2_critical(df)) << "g = " << g << ", df = " << df;
}

INSTANTIATE_TEST_SUITE_P(Anisotropies, HG, ::testing::Values(-0.9f, -0.3f, 0.0f, 0.5f, 0.9f, 0.99f));

TEST(EquiAngular, SamplesFollowTheirPdf) {
  vec3 o(0.f), d = normalize(vec3(0.2f, 0.1f, 1.f)), c(0.4f, -0.3f, 2.f);
  for (auto [t0, t1] : {std::pair{0.f, 5.f}, std::pair{1.f, 3.f}, std::pair{0.f, 1e30f}}) {
    EquiAngular e = equi_angular_setup(o, d, c, t0, t1);
    uint state = rng_init(3u, 1u, uint(t1));
    std::vector<double> ts;
    double hi = std::min(double(t1), 10.0);
    int outside = 0;
    for (int i = 0; i < 200000; ++i) {
      float t = equi_angular_sample(e, rng_next(state));
      ASSERT_GE(t, t0 - 1e-4f);
      if (t > hi)
        ++outside;
      else
        ts.push_back(t);
    }
    int df = 0;
    double chi2 = chi2_statistic(
        ts, t0, hi, 100, [&](double t) { return equi_angular_pdf(e, float(t)); }, &df, 200000.0);
    EXPECT_LT(chi2, chi2_critical(df)) << "[" << t0 << ", " << t1 << "]";
    double tail = 1 - simpson([&](double t) { return equi_angular_pdf(e, float(t)); }, t0, hi, 20000);
    EXPECT_NEAR(double(outside) / 200000, tail, 5e-3);
  }
}

// cone_clip against a brute-force scan of the line: every point strictly inside the returned interval is in
// the cone, every point outside it is not (up to 1e-3 of the segment's length around the ends). Random
// lines, apexes, axes and cone angles from 1 to 90 degrees, and lines through the apex.
// Injected: the front nappe taken as the near piece when A > 0 (a = lo instead of hi): fails at line 3.
TEST(ConeClip, MatchesABruteForceScan) {
  std::mt19937 gen(17);
  std::uniform_real_distribution<float> U(-1.f, 1.f);
  auto unit = [&] {
    vec3 v;
    do v = vec3(U(gen), U(gen), U(gen));
    while (length(v) < 0.1f || length(v) > 1.f);
    return normalize(v);
  };
  int checked = 0, hits = 0;
  for (int i = 0; i < 2000; ++i) {
    vec3 p = 2.f * vec3(U(gen), U(gen), U(gen)), axis = unit(), o = 3.f * vec3(U(gen), U(gen), U(gen));
    vec3 d = i % 10 == 0 ? normalize(p - o) : unit();  // every tenth line through the apex
    float angle = (i % 7 == 0) ? 90.f : 1.f + 89.f * (0.5f + 0.5f * U(gen));
    float c = std::cos(angle * 3.14159265f / 180.f);
    const float t0 = 0.f, t1 = 8.f;
    vec2 ab = cone_clip(o, d, p, axis, c, t0, t1);
    bool any_inside = false;
    for (int k = 0; k <= 4000; ++k) {
      float t = t0 + (t1 - t0) * float(k) / 4000.f;
      vec3 v = o + t * d - p;
      double inside = double(dot(v, axis)) - double(c) * double(length(v));
      if (std::abs(inside) < 1e-4) continue;  // on the surface: rounding decides
      bool in_interval = ab.x < ab.y && t > ab.x + 4e-3f && t < ab.y - 4e-3f;
      bool out_interval = !(ab.x < ab.y) || t < ab.x - 4e-3f || t > ab.y + 4e-3f;
      if (in_interval) {
        ASSERT_GT(inside, 0.0) << "line " << i << " t " << t << " [" << ab.x << ", " << ab.y << "]";
      }
      if (out_interval) {
        ASSERT_LT(inside, 0.0) << "line " << i << " t " << t << " [" << ab.x << ", " << ab.y << "]";
      }
      any_inside = any_inside || inside > 0;
      ++checked;
    }
    hits += any_inside;
  }
  EXPECT_GT(hits, 300);  // the lines meet cones often enough for the scan to mean something
  // No cone (a point light): the whole segment.
  vec2 all = cone_clip(vec3(0.f), vec3(0.f, 0.f, 1.f), vec3(1.f), vec3(0.f, -1.f, 0.f), -2.f, 0.5f, 3.f);
  EXPECT_EQ(all.x, 0.5f);
  EXPECT_EQ(all.y, 3.f);
}

// The stochastic trilinear lookup's corner choice follows the trilinear weights: a chi-square over the 8
// corners at fractional positions inside the cell, on a face and near others. Injected: u not rescaled
// after a decision (correlated axes) fails at every position (chi-square 458 to 415730 against 22 to 30),
// and so does the branch not taken rescaled as the taken one (400801 to 7.2e6).
TEST(TrilinearCorner, FollowsTheTrilinearWeights) {
  const vec3 fs[] = {vec3(0.3f, 0.7f, 0.5f), vec3(0.05f, 0.9f, 0.5f), vec3(0.f, 0.5f, 1e-3f),
                     vec3(0.999f, 0.25f, 0.6f)};
  const int n = 400000;
  for (vec3 f : fs) {
    uint state = rng_init(11u, uint(f.x * 1000), uint(f.y * 1000));
    double counts[8] = {};
    for (int i = 0; i < n; ++i) {
      ivec3 c = trilinear_corner(f, rng_next(state));
      counts[c.x + 2 * c.y + 4 * c.z] += 1;
    }
    double chi2 = 0;
    int df = -1;
    for (int c = 0; c < 8; ++c) {
      double w = (c & 1 ? f.x : 1 - f.x) * (c & 2 ? f.y : 1 - f.y) * (c & 4 ? f.z : 1 - f.z);
      if (w == 0) {
        EXPECT_EQ(counts[c], 0) << "corner " << c << " has weight 0";
        continue;
      }
      double e = w * n;
      if (e < 5) continue;  // rare corners: too few expected draws for the chi-square
      chi2 += (counts[c] - e) * (counts[c] - e) / e;
      ++df;
    }
    EXPECT_LT(chi2, chi2_critical(df)) << "f = (" << f.x << ", " << f.y << ", " << f.z << ")";
  }
}

TEST(TruncatedExponential, SamplesFollowTheirPdf) {
  for (float tau_total : {1e-5f, 0.3f, 2.f, 40.f}) {
    uint state = rng_init(9u, 2u, uint(tau_total * 100));
    std::vector<double> taus;
    for (int i = 0; i < 200000; ++i) {
      float tau = truncated_exp_sample_tau(tau_total, rng_next(state));
      ASSERT_GE(tau, 0.f);
      ASSERT_LE(tau, tau_total * (1 + 1e-5f));
      taus.push_back(tau);
    }
    double norm =
        simpson([&](double t) { return truncated_exp_pdf_tau(float(t), tau_total); }, 0, tau_total, 20000);
    EXPECT_NEAR(norm, 1.0, 1e-3) << tau_total;
    int df = 0;
    double chi2 = chi2_statistic(
        taus, 0, tau_total, 100, [&](double t) { return truncated_exp_pdf_tau(float(t), tau_total); }, &df);
    EXPECT_LT(chi2, chi2_critical(df)) << tau_total;
  }
}

TEST(NormalCdf, MatchesStdErfcAndInverts) {
  for (double x = -12; x <= 6; x += 0.37) {
    double ref = 0.5 * std::erfc(-x / std::sqrt(2.0));
    EXPECT_NEAR(normal_cdf(float(x)) / ref, 1.0, 2e-5) << x;  // float exp of x^2 / 2
    // The upper tail is not needed (truncated_gaussian mirrors into the lower one); float p near 1 has no
    // digits left for it.
    if (ref > 1e-30 && ref < 0.99) {
      EXPECT_NEAR(normal_cdf_inverse(float(ref)), x, 2e-4 * std::max(1.0, std::abs(x))) << x;
    }
  }
}

// Guide lobes: a Gaussian truncated to [t0, t1], inside, across and far beyond the interval on both sides.
TEST(TruncatedGaussian, IsNormalisedAndSamplesFollowThePdf) {
  struct Case {
    float mu, sigma, t0, t1;
  };
  const Case cases[] = {
      {5, 1, 0, 10},  {0.5f, 2, 0, 3},          {-3, 1, 0, 4},        {12, 1.5f, 0, 8}, {40, 2, 0, 10},
      {-40, 3, 1, 2}, {2, 1e-3f, 1.999f, 2.5f}, {3, 0.5f, 2.9f, 3.1f}};
  for (const Case& c : cases) {
    TruncatedGaussian g = truncated_gaussian(c.mu, c.sigma, c.t0, c.t1);
    double norm = simpson([&](double t) { return truncated_gaussian_pdf(g, float(t)); }, c.t0, c.t1, 200000);
    EXPECT_NEAR(norm, 1.0, 2e-3) << c.mu << " " << c.sigma;
    uint state = rng_init(17u, uint(c.mu * 10 + 100), uint(c.sigma * 1000));
    std::vector<double> ts;
    for (int i = 0; i < 200000; ++i) {
      float t = truncated_gaussian_sample(g, rng_next(state));
      ASSERT_TRUE(std::isfinite(t));
      ASSERT_GE(t, c.t0);
      ASSERT_LE(t, c.t1);
      ASSERT_GT(truncated_gaussian_pdf(g, t), 0.f) << t;
      ts.push_back(t);
    }
    int df = 0;
    double chi2 = chi2_statistic(
        ts, c.t0, c.t1, 100, [&](double t) { return truncated_gaussian_pdf(g, float(t)); }, &df);
    EXPECT_LT(chi2, chi2_critical(df)) << c.mu << " " << c.sigma << " [" << c.t0 << ", " << c.t1 << "]";
  }
  // Degenerate inputs fall back to uniform (or nothing), never NaN.
  TruncatedGaussian flat = truncated_gaussian(1, 0, 0, 2);
  EXPECT_FLOAT_EQ(truncated_gaussian_pdf(flat, 1.3f), 0.5f);
  EXPECT_TRUE(std::isfinite(truncated_gaussian_sample(flat, 0.3f)));
  TruncatedGaussian empty = truncated_gaussian(1, 1, 2, 2);
  EXPECT_EQ(truncated_gaussian_pdf(empty, 2.f), 0.f);
  EXPECT_TRUE(std::isfinite(truncated_gaussian_sample(empty, 0.5f)));
}

// The guide mixture exactly as trace.comp draws from it: a candidate picked by weight, then its truncated
// Gaussian; the pdf is the weighted sum. Candidates inside, straddling and beyond t_s, empty ones, and one
// whose mean lies outside [0, t_s] (weight 0).
TEST(GuideMixture, SamplesFollowThePdf) {
  const float t_s = 10.f;
  const vec4 prm(0.5f, 0.005f, 0.1f, 4.f);
  // States {W, N, m1 = W mu, m2 = W (mu^2 + sigma^2)} for known mu and sigma.
  auto state = [](float W, float N, float mu, float sigma) {
    return vec4(W, N, W * mu, W * (mu * mu + sigma * sigma));
  };
  struct Case {
    std::vector<vec4> states;
  };
  const Case cases[] = {
      {{state(1, 100, 3, 0.5f), state(2, 100, 7, 1), state(0.5f, 100, 9.8f, 2)}},
      {{state(1, 1, 5, 0), vec4(0), state(3, 50, 0.2f, 0.1f)}},
      {{state(4, 100, 12, 1), state(1, 1000, 6, 0.01f), state(1, 10, 1, 3)}},
      {{state(1, 100, 2, 0.3f), state(1, 100, 2, 0.3f), state(1, 100, 8, 0.3f), state(2, 3, 5, 4),
        state(1, 100, 0.1f, 0.05f), state(1, 100, 9.9f, 0.05f), state(1, 100, 5, 0.5f),
        state(0.1f, 100, 5, 5)}},
  };
  for (size_t ci = 0; ci < std::size(cases); ++ci) {
    GuideMixture m = guide_mixture_empty();
    for (const vec4& st : cases[ci].states) guide_mixture_add(m, st, t_s, prm);
    ASSERT_GT(m.total, 0.f);
    double norm = simpson([&](double t) { return guide_mixture_pdf(m, float(t)); }, 0, t_s, 400000);
    EXPECT_NEAR(norm, 1.0, 2e-3) << "case " << ci;
    uint rng = rng_init(23u, uint(ci), 5u);
    std::vector<double> ts;
    for (int i = 0; i < 200000; ++i) {
      uint c = guide_mixture_pick(m, rng_next(rng));
      ASSERT_GT(m.w[c], 0.f);
      float t = truncated_gaussian_sample(m.g[c], rng_next(rng));
      ASSERT_GE(t, 0.f);
      ASSERT_LE(t, t_s);
      ASSERT_GT(guide_mixture_pdf(m, t), 0.f) << t;
      ts.push_back(t);
    }
    int df = 0;
    double chi2 = chi2_statistic(
        ts, 0, t_s, 200, [&](double t) { return guide_mixture_pdf(m, float(t)); }, &df);
    EXPECT_LT(chi2, chi2_critical(df)) << "case " << ci;
  }
  // Nothing usable: the guide cannot sample and says so with a zero pdf.
  GuideMixture none = guide_mixture_empty();
  guide_mixture_add(none, vec4(0), t_s, prm);
  guide_mixture_add(none, state(1, 10, 20, 1), t_s, prm);
  EXPECT_EQ(none.total, 0.f);
  EXPECT_EQ(guide_mixture_pdf(none, 3.f), 0.f);
}

// Learning: the running means converge to the contribution-weighted moments of t, and a shift by delta
// moves the mean by delta and keeps the variance.
TEST(GuideState, LearnsWeightedMomentsAndShifts) {
  vec4 s(0);
  uint rng = rng_init(3u, 1u, 2u);
  // Contributions L = 2 at t ~ U[4, 6] and L = 0 elsewhere on [0, 10]: the weighted mean is 5, the
  // variance 1/3, and W tends to the mean contribution 2 * 0.2 = 0.4.
  double sum_w = 0, sum_wt = 0;
  for (int i = 0; i < 20000; ++i) {
    float t = 10 * rng_next(rng);
    float L = t >= 4 && t <= 6 ? 2.f : 0.f;
    s = guide_update(s, L, t, 1e9f, 0.f);  // alpha = 1/N: exact running means
    sum_w += L;
    sum_wt += L * t;
  }
  EXPECT_EQ(s.y, 20000.f);
  EXPECT_NEAR(s.x, sum_w / 20000, 1e-4);
  EXPECT_NEAR(guide_mean(s), sum_wt / sum_w, 1e-3);
  EXPECT_NEAR(guide_mean(s), 5.0, 0.05);
  double var = s.w / s.x - guide_mean(s) * guide_mean(s);
  EXPECT_NEAR(var, 1.0 / 3.0, 0.02);
  // With many samples the prior has no say: sigma is the sample's.
  EXPECT_NEAR(guide_sigma(s, 10.f, vec4(0.5f, 0.005f, 0.1f, 4.f)), std::sqrt(var), 1e-3);
  // The count is capped, and alpha never falls below min_alpha.
  vec4 c = guide_update(vec4(1, 1024, 5, 26), 0.f, 0.f, 1024.f, 0.01f);
  EXPECT_EQ(c.y, 1024.f);
  EXPECT_NEAR(c.x, 0.99f, 1e-6);
  vec4 sh = guide_shift(s, -1.5f);
  EXPECT_NEAR(guide_mean(sh), guide_mean(s) - 1.5, 1e-3);
  EXPECT_NEAR(sh.w / sh.x - guide_mean(sh) * guide_mean(sh), var, 1e-3);
  // A fresh state is pulled to the prior's width; a mean outside [0, t_s] weighs nothing.
  vec4 one = guide_update(vec4(0), 3.f, 2.f, 1024.f, 0.01f);
  EXPECT_EQ(one.y, 1.f);
  EXPECT_NEAR(guide_sigma(one, 10.f, vec4(0.5f, 0.005f, 0.1f, 4.f)), std::sqrt(4.0 / 5.0), 1e-5);
  EXPECT_EQ(guide_weight(one, 1.f), 0.f);
  EXPECT_EQ(guide_weight(one, 10.f), 3.f);
}

TEST(Cone, UniformConeStaysInsideAndIsUniformInCosine) {
  vec3 axis = normalize(vec3(1.f, 2.f, -0.5f));
  float cos_max = std::cos(0.3f);
  uint state = rng_init(1u, 1u, 1u);
  std::vector<double> cs;
  for (int i = 0; i < 100000; ++i) {
    const float u1 = rng_next(state), u2 = rng_next(state);  // in this order, as GLSL evaluates arguments
    vec3 w = sample_uniform_cone(axis, cos_max, vec2(u1, u2));
    cs.push_back(dot(w, axis));
    ASSERT_GE(cs.back(), cos_max - 1e-5);
  }
  int df = 0;
  double chi2 = chi2_statistic(
      cs, cos_max, 1, 50, [&](double) { return 1 / (1 - cos_max); }, &df);
  EXPECT_LT(chi2, chi2_critical(df));
}

// The power heuristic's two weights of one sample sum to 1 (so MIS stays unbiased) at any ratio of the
// densities, including 0, infinity and squares beyond the float range, and are p_a^2 / (p_a^2 + p_b^2).
TEST(MisPower, WeightsSumToOneAndMatchTheHeuristic) {
  const float inf = std::numeric_limits<float>::infinity();
  const float ps[] = {0.f, 1e-30f, 1e-3f, 0.5f, 1.f, 3.f, 1e20f, 3e38f, inf};
  for (float a : ps)
    for (float b : ps) {
      if (a == 0.f && b == 0.f) continue;  // a sample neither strategy can produce
      const float wa = mis_power(a, b), wb = mis_power(b, a);
      EXPECT_TRUE(std::isfinite(wa) && wa >= 0.f && wa <= 1.f) << a << " " << b;
      EXPECT_NEAR(wa + wb, 1.f, 1e-6f) << a << " " << b;
      const double da = a, db = b;
      if (std::isfinite(da * da + db * db) && da * da + db * db > 0) {
        EXPECT_NEAR(wa, da * da / (da * da + db * db), 1e-6) << a << " " << b;
      }
    }
  EXPECT_EQ(mis_power(2.f, 0.f), 1.f);  // the other strategy cannot produce the sample
  EXPECT_EQ(mis_power(0.f, 2.f), 0.f);
  EXPECT_NEAR(mis_power(1.f, 1.f), 0.5f, 1e-7f);
}

TEST(Color, LuminanceAndTonemapsAreBounded) {
  EXPECT_NEAR(luminance(vec3(1.f)), 1.f, 1e-6f);
  for (float x : {0.f, 0.5f, 1.f, 10.f, 1e8f}) {
    vec3 a = tonemap_aces(vec3(x)), r = tonemap_reinhard(vec3(x));
    EXPECT_GE(a.x, 0.f);
    EXPECT_LE(a.x, 1.f);
    EXPECT_LT(r.x, 1.f + 1e-6f);
  }
  vec3 hot = blackbody_rgb(6500.f);
  EXPECT_NEAR(hot.g, 1.f, 1e-3f);
  EXPECT_GT(blackbody_rgb(1500.f).r, blackbody_rgb(1500.f).b);
  EXPECT_EQ(blackbody_rgb(0.f).r, 0.f);
}

}  // namespace
