// `haze denoise`: the surface SVGF instance, and the volume instance where the frames have a volume signal,
// over an EXR sequence written by haze or another renderer.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "scene/scene.hpp"

namespace haze::render {

// The layers a frame must have (names as haze writes them; docs in README):
//   surface_demod.R/G/B (or R/G/B, divided here by albedo), albedo.R/G/B, normal.X/Y/Z, depth.Z, motion.X/Y;
// optional: depth_gradient.X/Y (else forward differences of depth), instance.ID (else 0 on surfaces),
// depth_prev.Z (else depth), volume.R/G/B (denoised by the volume instance when denoise.volume.enabled and
// the first frame has volume_motion.X/Y or a non-zero volume layer;
// reprojected with volume_motion.X/Y where present and denoise.volume_motion is virtual_points, else with
// motion.X/Y; the volume term of the denoised composite, else 0),
// surface_emission.R/G/B (with surface_demod: added back after remodulation; else 0).
// Frames are the folder's .exr files in name order. Writes, per frame, OUT/<name>.exr with the layers
// denoised, surface_denoised, surface_history and surface_denoised_variance (and volume_denoised,
// volume_history, volume_denoised_variance when the volume instance ran), and OUT/<name>.png; returns
// the stats (also written to OUT/stats.json). `settings` supplies denoise and render.exposure and
// render.tonemap. Throws a one-line Error naming the file and the layer for bad input.
nlohmann::json denoise_sequence(gpu::Context& ctx, const std::string& in_dir, const std::string& out_dir,
                                const scene::Scene& settings);

}  // namespace haze::render
