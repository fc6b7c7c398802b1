// FLIP image difference (docs/metrics.md), reimplemented from its papers:
//   LDR-FLIP: Andersson, Nilsson, Akenine-Möller, Oskarsson, Åström, Fairchild, "FLIP: A Difference
//             Evaluator for Alternating Images", HPG 2020.
//   HDR-FLIP: Andersson, Nilsson, Shirley, Akenine-Möller, "Visualizing Errors in Rendered High Dynamic
//             Range Images", Eurographics 2021 short paper.
// Formulas and parameters: docs/metrics.md. Both take linear RGB (or one grey channel), row 0 at the top.
#pragma once

#include <cstdint>
#include <vector>

#include "eval/metrics.hpp"

namespace haze::eval {

struct FlipOptions {
  // Pixels per degree of visual angle: 0.7 m from a 0.7 m wide monitor 3840 pixels across.
  double ppd = 67.0206;
  bool want_map = false;
};

struct FlipResult {
  double mean = 0;
  std::vector<float> map;  // per pixel in [0, 1], row 0 at top, only when want_map
};

// Channels with count 1 are grey; count >= 3 uses the first three as linear R, G, B; count 2 throws
// std::invalid_argument, as do sizes that differ from width * height.
// LDR-FLIP clamps the linear values to [0, 1] first (HDR data: everything above 1 reads as 1).
FlipResult flip_ldr(const Channels& test, const Channels& ref, int width, int height,
                    const FlipOptions& o = {});
// HDR-FLIP's exposure range from the reference: start and stop in stops (log2 of the scale), count >= 2
// exposures evenly spaced from start to stop (docs/metrics.md).
struct FlipExposures {
  double start = 0, stop = 0;
  int count = 2;
};
FlipExposures flip_hdr_exposures(const Channels& ref);
// HDR-FLIP: LDR-FLIP of exposure-compensated, tone-mapped pairs over an exposure range taken from the
// reference, the per-pixel maximum. Not symmetric: the exposure range comes from ref only.
FlipResult flip_hdr(const Channels& test, const Channels& ref, int width, int height,
                    const FlipOptions& o = {});

// Whether FLIP is defined for images with this many channels (1, or 3 and more).
bool flip_supports(uint32_t channel_count);

// An error map in [0, 1] as RGBA8 through matplotlib's magma colour map (for write_png_rgb8).
std::vector<uint32_t> magma_rgba8(const std::vector<float>& map);

}  // namespace haze::eval
