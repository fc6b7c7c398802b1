// `haze bench`: the benchmark suite. Every figure is a ratio of two times (or sizes) measured in the same run
// on the same device, medians of repeated timings after a warm-up; docs/benchmarks.md says what each means.
#pragma once

#include <string>
#include <vector>

#include "gpu/gpu.hpp"

namespace haze::bench {

// The parts of the suite, in the order they run (first_frame first: it must see no pipeline of the bench
// scene created earlier in the process).
const std::vector<std::string>& part_names();

struct Options {
  bool json = false;
  std::string size = "320x180";  // the bench scene's size; also the invocations of the volume_repr kernels
  int spp = 8;
  std::string denoise_sizes = "640x360,1920x1080";  // the SVGF instance's pass times at these sizes
  std::string guiding_size = "96x54";               // guided vs unguided, volume denoiser figures
  int guiding_seeds = 4;                            // 0: skip those figures
  int efficiency_seeds = 4;                         // estimator efficiency: renders per side (0: skip)
  double efficiency_scale = 1.0;                    // its image sizes and sample counts, times this
  std::string efficiency_cases;                     // comma-separated case names; empty: all
  std::string efficiency_set;  // JSON merged into side a of every efficiency case (a change to measure)
  std::string only;            // comma-separated part names; empty: all
  // The shaft sequence (bench/shafts_bench.hpp).
  std::string shafts_size = "192x108";
  int shafts_frames = 12;
  int shafts_reference_spp = 1024;
  std::string reference_dir;  // the shaft references' cache; "": $XDG_CACHE_HOME/haze/references
  std::string images_dir;     // PNGs of the shaft sequence's frames 0, 4 and the last; "": none
  std::string shafts_set;     // JSON merged into the shaft scene (e.g. '{"denoise": {"volume": {...}}}')
};

// The parts `only` names (when empty: all but efficiency, which runs only when named); throws a one-line
// error naming an unknown part and listing the valid ones.
std::vector<std::string> parse_only(const std::string& only);

int run(const Options& o, const gpu::ContextOptions& co);

}  // namespace haze::bench
