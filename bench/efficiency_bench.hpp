// Estimator efficiency in `haze bench`: efficiency = 1 / (relMSE x time) against a converged reference, the
// default estimator over the volpath baseline (pbrt-v4's VolPathIntegrator inside haze, render.estimator
// "volpath") on four scenes, and guided over unguided distance sampling on sheets of light. Both sides of
// each ratio run in the same process on the same device; over seeds, the ratio of the mean relMSE x time
// (not the mean of per-seed ratios), with the per-seed range as its spread.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"

namespace haze::bench {

struct EfficiencyOptions {
  int seeds = 4;              // renders per estimator and case
  int reference_factor = 16;  // the reference has this many times the default estimator's samples
  double scale = 1.0;         // image sizes and sample counts are the cases' times this (quick runs: 0.5)
  std::vector<std::string> cases;  // empty: all (dense_cloud, haze_shaft, point_in_box, env_cloud, sheets)
  nlohmann::json set_a = nlohmann::json::object();  // merged into side a of every case (not the reference)
};

// The case names in the order they run.
const std::vector<std::string>& efficiency_case_names();

// A case's scene (without estimator, guiding or seed) at `scale` of its size: tests render the bench's
// scenes.
nlohmann::json efficiency_case_scene(const std::string& name, double scale);

nlohmann::json bench_efficiency(gpu::Context& ctx, const EfficiencyOptions& o);
void print_efficiency(const nlohmann::json& j);

// relMSE of x against a reference whose own per-value variance of the mean is ref_var, corrected for the
// reference's noise: mean over values of ((x - r)^2 - ref_var) / (r^2 + 0.01). With x independent of the
// reference, its expectation is the relMSE against the converged image (up to the denominator's noise), so a
// reference of a few times the samples suffices.
double relmse_corrected(const std::vector<float>& x, const std::vector<float>& ref,
                        const std::vector<float>& ref_var);

}  // namespace haze::bench
