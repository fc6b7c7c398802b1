// The shaft sequence of `haze bench --only shafts` (docs/denoising.md, shafts that survive denoising): low
// sun through a wall of vertical planks into haze, so that the air holds sheets of light; a camera moving
// past them and a small smoke puff drifting through them. Each frame is denoised as `haze render` does and
// measured against a converged reference of the same frame (cached by eval::make_reference): relMSE and
// FLIP of the composite and of the volume term, the contrast of the sheets on masks taken from the
// reference, the mean luminance of each instance, the volume history where the reprojection is wrong, and
// the temporal stability of the sequence.
#pragma once

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "render/output.hpp"
#include "render/renderer.hpp"

namespace haze::bench {

struct ShaftsOptions {
  int width = 192, height = 108;
  int frames = 12;  // frames rendered, 0..frames-1, of a camera move and a puff's drift over 24 frames
  int spp = 4;
  int reference_spp = 1024;          // per frame, each camera sample with reference_volume_samples
  int reference_volume_samples = 4;  // distance samples per camera sample in the reference
  std::string reference_dir;         // the references' cache (a folder per key); "" : $XDG_CACHE_HOME/haze
  std::string images_dir;            // "" : none; else PNGs of frames 0, 4 and the last
  std::string label = "shafts";      // prefix of the PNG names
  nlohmann::json set;                // applied to the scene after it is made (e.g. {"denoise": {...}})
  // Also run the sequence with the volume instance reduced to its temporal accumulation and report the sheet
  // contrast that the reprojection alone keeps.
  bool accumulation_floor = true;
};

// The sequence's scene: `scenes/shafts.json` is shafts_scene(ShaftsOptions{}) as written by the bench.
nlohmann::json shafts_scene(const ShaftsOptions& o);

// Sheet masks of a reference volume term (luminance per pixel, row 0 at the top): 1 inside a lit sheet
// (above 1.25 x its local mean over a box of half-width `radius`), -1 between sheets (below 0.8 x), 0
// elsewhere (and where the local mean is below 5% of the image's mean luminance).
std::vector<int8_t> sheet_masks(const std::vector<float>& Y, int width, int height, int radius);
// Mean luminance inside the sheets over the mean between them.
double sheet_contrast(const std::vector<float>& Y, const std::vector<int8_t>& mask);

// The 8x8 block pattern of an image: the mean luminance step across pixel pairs that straddle a boundary of
// the 8x8 grid (x or y a multiple of 8) over the mean step between the other neighbours; about 1 without
// blocks.
double block_ratio(const std::vector<float>& Y, int width, int height);

// Luminance planes of an image's layers.
std::vector<float> luminance_of(const std::vector<glm::vec3>& rgb);

// Runs the sequence; per-frame figures and their summary as JSON (printed by print_shafts).
nlohmann::json bench_shafts(gpu::Context& ctx, const ShaftsOptions& o);
void print_shafts(const nlohmann::json& j);

}  // namespace haze::bench
