// Light choice by power against uniform choice in `haze bench`: a hazy room lit by one bright point light
// and many dim ones, rendered at equal samples with lights.choice "power" and "uniform", over seeds. The
// figure is the ratio of the per-pixel variances of L (uniform / power: > 1, power wins); the images' means
// are compared too (both are unbiased). Two costs: trace time per sample with power / uniform choice, and
// lit by an environment map / by a constant environment. Ratios from one run on one device.
#pragma once

#include <nlohmann/json.hpp>

#include "gpu/gpu.hpp"

namespace haze::bench {

struct LightChoiceBenchOptions {
  int width = 96, height = 54;
  int seeds = 4;
  int spp = 16;
  int dim_lights = 15;  // besides the bright one
  double bright = 400;  // intensity of the bright light
  double dim = 2;       // intensity of each dim light
  int time_reps = 16;   // adjacent pairs of trace timings for each cost ratio
};

nlohmann::json bench_light_choice(gpu::Context& ctx, const LightChoiceBenchOptions& o);
void print_light_choice(const nlohmann::json& j);

}  // namespace haze::bench
