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

// Per-pixel sample mean and variance of the mean for one accumulated channel (sum at offset `sum`,
// sum of squares at `sq`).
struct Estimate {
  std::vector<double> mean, var_of_mean;
};
Estimate estimate(const render::Renderer& r, uint32_t sum, uint32_t sq);

// Pixel-centre camera ray directions, as the shader computes them (pixel_jitter off).
std::vector<glm::dvec3> camera_directions(const scene::Scene& s);

// Pooled z statistic of sum(mean - ref) / sqrt(sum var_of_mean) over the pixels where ref is given.
double z_score(const Estimate& e, const std::vector<double>& ref);

// Composite Simpson on [a, b] with n (even) intervals.
double integrate(const std::function<double(double)>& f, double a, double b, int n = 20000);

}  // namespace haze::test
