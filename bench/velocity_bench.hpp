// The volume denoiser on a moving smoke sequence in `haze bench`: `haze vdb make`'s translating cloud with
// its velocity grid, denoised with the virtual points moved by the velocity against moved by the medium's
// transform alone (rigid-only: here it does not move), relMSE of the denoised volume signal against a
// reference sequence, over seeds. Ratios from one run on one device.
#pragma once

#include <nlohmann/json.hpp>

#include "gpu/gpu.hpp"

namespace haze::bench {

struct VelocityBenchOptions {
  int width = 96, height = 54;
  int seeds = 4;            // repetitions for the spread
  int frames = 8;           // sequence length
  int sequence_spp = 2;     // samples per frame in the sequence
  int reference_spp = 128;  // samples per frame of the reference
  double move = 0.06;       // world units per frame along x (the cloud's diameter is 1.6)
};

nlohmann::json bench_velocity(gpu::Context& ctx, const VelocityBenchOptions& o);
void print_velocity(const nlohmann::json& j);

}  // namespace haze::bench
