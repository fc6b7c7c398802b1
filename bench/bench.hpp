// `haze bench`: throughput figures and each pass's time as a ratio to a copy kernel over the same
// amount of data, measured in one run on one device.
#pragma once

#include <string>

#include "gpu/gpu.hpp"

namespace haze::bench {

struct Options {
  bool json = false;
  std::string size = "320x180";
  int spp = 8;
  std::string denoise_sizes = "640x360,1920x1080";  // the SVGF instance's pass times at these sizes
  std::string guiding_size = "96x54";               // guided vs unguided, volume denoiser figures
  int guiding_seeds = 4;                            // 0: skip those figures
};

int run(const Options& o, const gpu::ContextOptions& co);

}  // namespace haze::bench
