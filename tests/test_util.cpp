#include "test_util.hpp"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "shaders/glsl.hpp"

namespace haze::test {

gpu::Context& context() {
  static gpu::Context ctx{gpu::ContextOptions{}};
  return ctx;
}

scene::Scene make_scene(const nlohmann::json& j) {
  return scene::from_json(j, "test scene", "");
}

Estimate estimate(const render::Renderer& r, uint32_t sum, uint32_t sq, int channels) {
  std::vector<double> acc = r.accum();
  size_t pixels = acc.size() / glsl::ACC_STRIDE;
  Estimate e;
  e.channels = channels;
  for (size_t p = 0; p < pixels; ++p) {
    const double* a = &acc[p * glsl::ACC_STRIDE];
    double n = r.samples() - a[glsl::ACC_DROPPED];
    for (int c = 0; c < channels; ++c) {
      double s = a[sum + c], s2 = a[sq + c];
      double m = n > 0 ? s / n : 0;
      double var = n > 1 ? std::max(0.0, (s2 / n - m * m) * n / (n - 1)) : 0;
      e.mean.push_back(m);
      e.var_of_mean.push_back(n > 0 ? var / n : 0);
    }
  }
  return e;
}

std::vector<glm::dvec3> camera_directions(const scene::Scene& s) {
  const auto& c = s.camera;
  glm::dvec3 fwd = glm::normalize(glm::dvec3(c.target - c.position));
  glm::dvec3 right = glm::normalize(glm::cross(fwd, glm::dvec3(c.up)));
  glm::dvec3 up = glm::cross(right, fwd);
  double th = std::tan(glm::radians(double(c.fov_y)) * 0.5);
  double aspect = double(s.render.width) / s.render.height;
  std::vector<glm::dvec3> dirs;
  for (int y = 0; y < s.render.height; ++y)
    for (int x = 0; x < s.render.width; ++x) {
      double nx = (x + 0.5) / s.render.width * 2 - 1, ny = (y + 0.5) / s.render.height * 2 - 1;
      dirs.push_back(glm::normalize(fwd + nx * th * aspect * right - ny * th * up));
    }
  return dirs;
}

double z_score(const Estimate& e, const std::vector<double>& ref, int channel) {
  double diff = 0, var = 0;
  for (size_t p = 0; p < ref.size(); ++p) {
    if (std::isnan(ref[p])) continue;
    diff += e.mean[p * e.channels + channel] - ref[p];
    var += e.var_of_mean[p * e.channels + channel];
  }
  return var > 0 ? diff / std::sqrt(var) : (diff == 0 ? 0 : 1e9);
}

namespace {

// Upper quantile of the standard normal at probability p (Acklam's approximation, shared with the shaders).
double normal_quantile_upper(double p) {
  return -double(glsl::normal_cdf_inverse(float(p)));
}

// Chi-square critical value with `dof` degrees of freedom at upper-tail probability alpha (Wilson-Hilferty).
double chi2_critical(int dof, double alpha) {
  const double z = normal_quantile_upper(alpha);
  const double a = 2.0 / (9.0 * dof);
  const double t = 1 - a + z * std::sqrt(a);
  return dof * t * t * t;
}

BiasTest run_test(const Estimate& e, const std::function<double(size_t)>& ref,
                  const std::function<double(size_t)>& extra_var, double alpha, double exact_tolerance) {
  BiasTest t;
  const size_t C = size_t(e.channels);
  std::vector<double> diff(C, 0.0), var(C, 0.0);
  t.chi2.assign(C, 0.0);
  t.dof.assign(C, 0);
  for (size_t i = 0; i < e.mean.size(); ++i) {
    const double r = ref(i);
    if (std::isnan(r)) continue;
    const size_t c = i % C;
    // The estimator's float arithmetic and sums are good to about kFloatPrecision: a floor of the error.
    const double v_float = kFloatPrecision * r * kFloatPrecision * r;
    const double v_sample = e.var_of_mean[i] + extra_var(i);
    const double v = v_sample > 0 ? v_sample + v_float : 0.0;
    const double d = e.mean[i] - r;
    diff[c] += d;
    var[c] += v;
    if (v > 0 && std::sqrt(v) <= kMaxRelativeError * std::abs(e.mean[i])) {
      t.chi2[c] += d * d / v;
      ++t.dof[c];
    } else if (v == 0 && std::abs(d) <= exact_tolerance * std::max(1.0, std::abs(r))) {
      // Matches without variance (deterministic, or a 0/1 estimator that never missed).
    } else if (v > 0 || e.mean[i] == 0) {
      // Too few contributions for a normal z (a few large values, or none yet): pooled z only.
      ++t.undersampled;
    } else {
      ++t.exact_mismatches;
    }
    ++t.values;
  }
  const double a = alpha / double(2 * C);  // Bonferroni over the chi-square and pooled z of each channel
  for (size_t c = 0; c < C; ++c) {
    t.pooled_z.push_back(var[c] > 0 ? diff[c] / std::sqrt(var[c]) : 0.0);
    t.chi2_critical.push_back(t.dof[c] > 0 ? chi2_critical(t.dof[c], a) : 0.0);
  }
  t.z_critical = normal_quantile_upper(a / 2);
  return t;
}

}  // namespace

bool BiasTest::passed() const {
  if (exact_mismatches > 0 || undersampled > kMaxUndersampled * values) return false;
  for (size_t c = 0; c < chi2.size(); ++c)
    if (!(chi2[c] <= chi2_critical[c]) || !(std::abs(pooled_z[c]) < z_critical)) return false;
  return true;
}

std::string BiasTest::describe() const {
  std::string x, z;
  for (size_t c = 0; c < chi2.size(); ++c) {
    x += fmt::format("{}{:.1f}/{:.1f} (dof {})", c ? ", " : "", chi2[c], chi2_critical[c], dof[c]);
    z += fmt::format("{}{:.2f}", c ? ", " : "", pooled_z[c]);
  }
  return fmt::format(
      "chi2/critical per channel [{}], pooled z [{}] (critical {:.2f}), {} exact mismatches, {} of {} values "
      "undersampled",
      x, z, z_critical, exact_mismatches, undersampled, values);
}

BiasTest bias_test(const Estimate& e, const std::vector<double>& ref, double alpha, double exact_tolerance) {
  const bool per_channel = ref.size() == e.mean.size();
  EXPECT_TRUE(per_channel || ref.size() == e.pixels()) << "reference size " << ref.size();
  return run_test(
      e, [&](size_t i) { return per_channel ? ref[i] : ref[i / size_t(e.channels)]; },
      [](size_t) { return 0.0; }, alpha, exact_tolerance);
}

BiasTest two_sample_test(const Estimate& a, const Estimate& b, double alpha) {
  EXPECT_EQ(a.mean.size(), b.mean.size());
  EXPECT_EQ(a.channels, b.channels);
  return run_test(
      a, [&](size_t i) { return b.mean[i]; }, [&](size_t i) { return b.var_of_mean[i]; }, alpha, 1e-3);
}

void expect_unbiased(const BiasTest& t, const std::string& what) {
  EXPECT_TRUE(t.passed()) << what << ": " << t.describe();
  std::cout << what << ": " << t.describe() << "\n";
}

void expect_no_discards(const render::FrameCounters& c, const std::string& what) {
  EXPECT_EQ(c.non_finite, 0u) << what;
  EXPECT_EQ(c.step_cap, 0u) << what;
  EXPECT_EQ(c.majorant, 0u) << what;
}

render::Image render_checked(render::Renderer& r, int spp, const std::string& what) {
  r.add_samples(spp);
  render::Image img = r.resolve();
  expect_no_discards(img.counters, what);
  EXPECT_EQ(context().validation_messages(), 0u) << what;
  return img;
}

double integrate(const std::function<double(double)>& f, double a, double b, int n) {
  if (n % 2) ++n;
  double h = (b - a) / n, s = f(a) + f(b);
  for (int i = 1; i < n; ++i) s += f(a + i * h) * (i % 2 ? 4 : 2);
  return s * h / 3;
}

}  // namespace haze::test
