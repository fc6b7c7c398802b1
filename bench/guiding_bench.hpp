// Distance guiding and the volume denoiser in `haze bench`: guided against unguided volume error at equal
// GPU time on light-shaft scenes (spread over seeds), and the volume instance with the virtual points'
// motion against the surface motion on a panning camera, with its time and memory next to the surface
// instance's. Ratios from one run on one device.
#pragma once

#include <nlohmann/json.hpp>

#include "gpu/gpu.hpp"

namespace haze::bench {

struct GuidingBenchOptions {
  int width = 96, height = 54;
  int spp = 16;               // unguided samples per pixel at the measured time
  int seeds = 4;              // repetitions for the spread
  int reference_factor = 32;  // the reference has spp * reference_factor samples
  int frames = 8;             // panning sequence length
  int sequence_spp = 2;       // samples per frame in the sequence
};

nlohmann::json bench_guiding(gpu::Context& ctx, const GuidingBenchOptions& o);
void print_guiding(const nlohmann::json& j);

}  // namespace haze::bench
