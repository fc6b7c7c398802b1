// Helpers for GPU estimator tests: one Vulkan context per process, scenes from JSON, per-pixel means and
// variances of the accumulated layers, and the z-test.
#pragma once

#include <functional>
#include <glm/glm.hpp>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "render/renderer.hpp"
#include "scene/scene.hpp"

namespace haze::test {

gpu::Context& context();  // validation on (HAZE_VALIDATION=1 in the test environment)

scene::Scene make_scene(const nlohmann::json& j);

// Per-pixel sample means and variances of the mean of `channels` consecutive accumulated channels (sums
// from offset `sum`, sums of squares from `sq`), index pixel * channels + channel. Each pixel's sample
// count leaves out the samples it dropped (ACC_DROPPED).
struct Estimate {
  std::vector<double> mean, var_of_mean;
  int channels = 1;
  size_t pixels() const { return mean.size() / size_t(channels); }
};
Estimate estimate(const render::Renderer& r, uint32_t sum, uint32_t sq, int channels = 1);

// Pixel-centre camera ray directions, as the shader computes them (pixel_jitter off).
std::vector<glm::dvec3> camera_directions(const scene::Scene& s);

// Pooled z statistic of sum(mean - ref) / sqrt(sum var_of_mean) over the pixels where ref is given (not NaN),
// for one channel; ref is per pixel.
double z_score(const Estimate& e, const std::vector<double>& ref, int channel = 0);

// A test of an estimate against a reference, per pixel and per channel, at a significance alpha fixed
// before looking: the per-pixel z-scores z = (mean - ref) / sqrt(var_of_mean), summed as z^2 over the
// pixels of each channel against the chi-square critical value (Wilson-Hilferty), and the pooled z of each
// channel against the two-sided normal quantile. Channels share their samples (a grey medium makes them
// equal), so each channel is its own test; the 2 x channels statistics split alpha (Bonferroni).
// A z-score is normal only when the mean is made of many contributions: a value whose standard error is
// above kMaxRelativeError of its mean (or that is 0 with no variance: no contribution yet) enters the pooled
// z only, and at most kMaxUndersampled of the values may be such. A value with no variance but a nonzero
// mean must match ref to `exact_tolerance` (relative: float rounding, or a 0/1 estimator that never missed).
// `ref` holds one value per pixel (every channel) or per pixel and channel; NaN entries are skipped. For a
// two-sample test the second estimate's variance adds to each pixel's, and every variance gets a floor of
// float rounding, (kFloatPrecision x ref)^2.
inline constexpr double kMaxRelativeError = 0.5;
inline constexpr double kFloatPrecision = 1e-5;
inline constexpr double kMaxUndersampled = 0.1;
struct BiasTest {
  std::vector<double> chi2, pooled_z;  // per channel
  std::vector<int> dof;                // values in the chi-square, per channel
  std::vector<double> chi2_critical;
  double z_critical = 0;     // two-sided
  int exact_mismatches = 0;  // deterministic values off ref by more than the tolerance
  int undersampled = 0;      // values in the pooled z only
  int values = 0;            // values with a reference
  bool passed() const;
  std::string describe() const;
};
inline constexpr double kAlpha = 1e-4;
BiasTest bias_test(const Estimate& e, const std::vector<double>& ref, double alpha = kAlpha,
                   double exact_tolerance = 1e-3);
BiasTest two_sample_test(const Estimate& a, const Estimate& b, double alpha = kAlpha);
// Asserts the test's verdict, naming `what` and printing the statistics.
void expect_unbiased(const BiasTest& t, const std::string& what);

// Requires that a frame's samples discarded nothing: no non-finite radiance, no step-cap abort, no
// majorant violation.
void expect_no_discards(const render::FrameCounters& c, const std::string& what);

// Adds `spp` samples and resolves; nothing may be discarded and the validation layer says nothing.
render::Image render_checked(render::Renderer& r, int spp, const std::string& what);

// The bound on |z| of the pooled z-tests: a two-sided significance of 1e-4.
inline constexpr double kZ = 3.89;

// Composite Simpson on [a, b] with n (even) intervals.
double integrate(const std::function<double(double)>& f, double a, double b, int n = 20000);

}  // namespace haze::test
