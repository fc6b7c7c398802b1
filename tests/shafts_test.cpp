// The shaft sequence of `haze bench --only shafts` (bench/shafts_bench.hpp) at a size lavapipe runs in
// seconds: sunlight through planks into haze, a moving camera, a drifting puff, 6 frames of 4 spp, against
// references of 128 spp x 4 volume samples cached in the build folder (the first run makes them, about
// half a minute). The denoisers' defaults are compared with the volume instance's former settings (the
// surface G-buffer as its geometry, gather normalization, SVGF's sample sigma, the seed's constants) in the
// same run; thresholds sit within about 3x of the figures measured here (docs/denoising.md has the
// figures at the bench's 192x108). Goals of issue 13 that are not met and so not tested here: the sheets'
// contrast within 15% of the reference's by frame 4 (-55% at this size, -36% at 192x108) and a volume
// history that drops where the reprojection is wrong.
#include <gtest/gtest.h>

#include <fstream>
#include <iostream>

#include "bench/shafts_bench.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using nlohmann::json;

json run(const json& set) {
  bench::ShaftsOptions o;
  o.width = 96;
  o.height = 54;
  o.frames = 6;
  o.reference_spp = 128;
  o.reference_dir = HAZE_SHAFTS_REFERENCES;
  o.set = set;
  return bench::bench_shafts(context(), o);
}

// Mean over frames 2..5 of a per-frame figure (frames 0 and 1 have little history).
double late_mean(const json& j, const char* group, const char* key) {
  double s = 0;
  for (int f = 2; f < 6; ++f) s += j["per_frame"][f][group][key].get<double>();
  return s / 4;
}

TEST(Shafts, SheetsMeanAndBlocksImproveOnTheFormerVolumeSettings) {
  const json now = run(json());
  const json former = run({{"denoise",
                            {{"volume",
                              {{"geometry", "surface"},
                               {"normalization", "gather"},
                               {"filter_sigma", "sample"},
                               {"accumulate", 0.902},
                               {"adapt_ipr", 15},
                               {"phi_luminance", 4},
                               {"taa_blend", 0.804}}}}}});
  const json splat = run({{"denoise", {{"surface", {{"normalization", "splat"}}}}}});

  const double mean_now = late_mean(now, "mean_luminance_over_reference", "volume");
  const double mean_former = late_mean(former, "mean_luminance_over_reference", "volume");
  const double surface_gather = late_mean(now, "mean_luminance_over_reference", "surface");
  const double surface_splat = late_mean(splat, "mean_luminance_over_reference", "surface");
  const double noisy = late_mean(now, "mean_luminance_over_reference", "volume_noisy");
  auto contrast = [](const json& j) {
    return j["per_frame"][4]["sheet_contrast"]["volume_over_reference"].get<double>();
  };
  auto blocks = [](const json& j) {
    return j["per_frame"][0]["block_ratio"]["volume"].get<double>() /
           j["per_frame"][0]["block_ratio"]["volume_reference"].get<double>();
  };
  auto flip = [](const json& j) { return j["per_frame"][4]["flip_ldr"]["composite"].get<double>(); };
  std::cout << "volume mean error, frames 2-5: defaults " << mean_now << ", former " << mean_former
            << " (noisy input " << noisy << ")\n"
            << "surface mean error, frames 2-5: gather (default) " << surface_gather << ", splat "
            << surface_splat << "\n"
            << "sheet contrast / reference's at frame 4: defaults " << contrast(now) << ", former "
            << contrast(former) << "\n"
            << "8x8 block pattern at frame 0 / reference's: defaults " << blocks(now) << ", former "
            << blocks(former) << "\n"
            << "FLIP of the composite at frame 4: defaults " << flip(now) << ", former " << flip(former)
            << "\n";

  // Energy: the volume instance's splat normalization keeps the mean (measured +0.4% to -2.1% over runs:
  // guiding learns in a different order each run, and the noisy input's own figure moves by as much, +0.7% to
  // +3.1%); the former gather lost 16 to 17%. Catches: a splat pass that does not divide by the weight sums
  // (measured -81%), and gather for the volume (the former settings).
  EXPECT_LT(std::abs(mean_now), 0.05);
  EXPECT_LT(mean_former, -0.10);
  // The surface instance keeps SVGF's gather by default (-18.5% here on this sequence's sparse noise); splat,
  // the documented remedy, keeps the mean (measured -0.4%).
  EXPECT_LT(std::abs(surface_splat), 0.03);
  EXPECT_LT(surface_gather, -0.10);
  // Sheets: the contrast lost at frame 4 shrinks (measured -55% against -62%; at this size a sheet is 2-4
  // pixels wide), though far from the goal. Catches: filter_sigma "estimate" ignored (the luminance term
  // steered by one frame's sigma: measured a gain of 0.016 instead of 0.070). The volume's geometry alone
  // moves this figure too little at this size to be caught here (0.438 with the surface G-buffer);
  // the bench measures it at 192x108 (docs/denoising.md).
  EXPECT_GT(contrast(now) - contrast(former), 0.04);
  // Frame 0 shows no 8x8 blocks (measured 1.04 of the reference's step ratio, the former 1.34).
  EXPECT_LT(blocks(now), 1.15);
  EXPECT_GT(blocks(former), 1.2);
  // The composite is closer to the reference by FLIP (measured 0.153 against 0.171).
  EXPECT_LT(flip(now), flip(former) - 0.007);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// scenes/shafts.json is the bench's sequence, 24 frames at 192x108: the file a user renders and the scene the
// figures in docs/denoising.md come from stay one.
TEST(Shafts, ShippedSceneIsTheBenchSequence) {
  bench::ShaftsOptions o;
  o.frames = 24;
  std::ifstream f(std::string(HAZE_SOURCE_DIR) + "/scenes/shafts.json");
  ASSERT_TRUE(f.good());
  EXPECT_EQ(json::parse(f), bench::shafts_scene(o));
  EXPECT_NO_THROW(make_scene(bench::shafts_scene(o)));
}

}  // namespace
}  // namespace haze::test
