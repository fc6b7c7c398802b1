// The shaft sequence of `haze bench --only shafts` (bench/shafts_bench.hpp) at a size lavapipe runs in
// seconds: sunlight through planks into haze, a moving camera, a drifting puff, 6 frames of 4 spp, against
// references of 128 spp x 4 volume samples cached in the build folder (the first run makes them, about
// half a minute). The denoisers' defaults are compared with the volume instance's former settings (the
// surface G-buffer as its geometry, gather normalization, SVGF's sample sigma, the seed's constants) in the
// same run; thresholds sit within about 3x of the figures measured here (docs/denoising.md has the
// figures at the bench's 192x108). Issue 13's goal for the sheets' contrast is tested at 192x108 (the last
// test): at 96x54 a sheet is 1-3 pixels wide and the defaults keep -26% of it at frame 4.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <iostream>

#include "bench/shafts_bench.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using nlohmann::json;

json run(const json& set, bool accumulation_floor = false, int width = 96, int height = 54) {
  bench::ShaftsOptions o;
  o.accumulation_floor = accumulation_floor;
  o.width = width;
  o.height = height;
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
                               {"taa_blend", 0.804},
                               {"history_test", 0},
                               {"feedback", "filtered"},
                               {"adapt_strength", 0.901},
                               {"iterations", 5},
                               {"taa_clamp", "minmax"},
                               {"taa_gamma", 1},
                               {"epipolar", 0}}}}}});
  const json centre = run({{"denoise", {{"surface", {{"luminance_sigma", "centre"}}}}}});
  const json untested = run({{"denoise", {{"volume", {{"history_test", 0}}}}}});
  const json sample_sigma = run({{"denoise", {{"volume", {{"filter_sigma", "sample"}}}}}});
  // A sharper variant of the defaults: a less eager history test (k 0.5) and short TAA.
  json sharp_volume = {{"feedback", "accumulated"},
                       {"history_test", 0.5},
                       {"adapt_strength", 0},
                       {"iterations", 3},
                       {"taa_blend", 0.3}};
  const json sharp = run({{"denoise", {{"volume", sharp_volume}}}});
  sharp_volume["history_witness"] = "history";
  const json self_judged = run({{"denoise", {{"volume", sharp_volume}}}});

  const double mean_now = late_mean(now, "mean_luminance_over_reference", "volume");
  const double mean_former = late_mean(former, "mean_luminance_over_reference", "volume");
  const double surface_pair = late_mean(now, "mean_luminance_over_reference", "surface");
  const double surface_centre = late_mean(centre, "mean_luminance_over_reference", "surface");
  const double noisy = late_mean(now, "mean_luminance_over_reference", "volume_noisy");
  const double mean_sharp = late_mean(sharp, "mean_luminance_over_reference", "volume");
  const double mean_self_judged = late_mean(self_judged, "mean_luminance_over_reference", "volume");
  auto contrast = [](const json& j) {
    return j["per_frame"][4]["sheet_contrast"]["volume_over_reference"].get<double>();
  };
  auto blocks = [](const json& j) {
    return j["per_frame"][0]["block_ratio"]["volume"].get<double>() /
           j["per_frame"][0]["block_ratio"]["volume_reference"].get<double>();
  };
  auto flip = [](const json& j) { return j["per_frame"][4]["flip_ldr"]["composite"].get<double>(); };
  // The volume history where the reprojection is wrong over where it is right, frames 2..5.
  auto history_drop = [](const json& j) {
    return late_mean(j, "volume_history", "mean_where_wrong") /
           late_mean(j, "volume_history", "mean_where_right");
  };
  std::cout << "volume mean error, frames 2-5: defaults " << mean_now << ", former " << mean_former
            << ", sharp settings " << mean_sharp << ", sharp judging the history itself " << mean_self_judged
            << " (noisy input " << noisy << ")\n"
            << "surface mean error, frames 2-5: luminance_sigma pair (default) " << surface_pair
            << ", centre " << surface_centre << "\n"
            << "sheet contrast / reference's at frame 4: defaults " << contrast(now) << ", former "
            << contrast(former) << ", filter_sigma sample " << contrast(sample_sigma) << ", sharp settings "
            << contrast(sharp) << "\n"
            << "8x8 block pattern at frame 0 / reference's: defaults " << blocks(now) << ", former "
            << blocks(former) << "\n"
            << "FLIP of the composite at frame 4: defaults " << flip(now) << ", former " << flip(former)
            << "\n"
            << "volume history where wrong / where right, frames 2-5: defaults " << history_drop(now)
            << ", history_test 0 " << history_drop(untested) << "\n";

  // Energy: the volume instance's splat normalization keeps the mean (measured -1.2% here, the noisy input's
  // own figure -1.0%; -1.4% over frames 0-7 at the bench's 192x108); the former settings' gather loses 6.6%.
  // With the sharp variant's history test the test judging the previous output keeps it too (-0.5%); judging
  // the noisy history itself it cuts bright histories of skewed noise more often than dark ones (-5.1%).
  // Catches: a splat pass that does not divide by the weight sums (measured -81%), gather for the volume (the
  // former settings), and the witness ignored (history_witness "output" judged like "history").
  EXPECT_LT(std::abs(mean_now), 0.03);
  EXPECT_LT(mean_former, -0.04);
  EXPECT_LT(std::abs(mean_sharp), 0.03);
  EXPECT_LT(mean_self_judged, mean_sharp - 0.025);
  // The surface instance's gather with the luminance term scaled by the pair's sigma keeps the mean (measured
  // -2.3% here, -1.7% at the bench's 192x108); with the centre's sigma (SVGF's) dark centres refuse their
  // bright neighbours and the mean drops (measured -6.6%). Catches: luminance_sigma "pair" ignored.
  EXPECT_LT(std::abs(surface_pair), 0.04);
  EXPECT_LT(surface_centre, surface_pair - 0.02);
  // Sheets: the contrast lost at frame 4 shrinks (measured -26% against the former -58%; at this size a
  // sheet is 1-3 pixels wide). Catches: filter_sigma "estimate" ignored (the luminance term steered by one
  // frame's sigma: measured 0.699 against 0.735). The volume's geometry alone moves this figure too little at
  // this size to be caught here; the bench measures it at 192x108 (docs/denoising.md).
  EXPECT_GT(contrast(now) - contrast(former), 0.1);
  EXPECT_GT(contrast(now) - contrast(sample_sigma), 0.03);
  // Frame 0 shows no 8x8 blocks (measured 0.947 of the reference's step ratio, the former 1.35).
  EXPECT_LT(blocks(now), 1.15);
  EXPECT_GT(blocks(former), 1.2);
  // The composite is closer to the reference by FLIP (measured 0.1141 against 0.1389).
  EXPECT_LT(flip(now), flip(former) - 0.007);
  // The volume history drops where the reprojection is wrong (the reference's luminance at the reprojected
  // position differs by more than 30%): wrong / right 0.759 with the history test, 0.987 without it. Catches:
  // the history test switched off or ignored (history_test 0, the `untested` run).
  EXPECT_LT(history_drop(now), 0.9);
  EXPECT_GT(history_drop(untested), 0.98);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The volume instance reduced to its temporal accumulation (the bench's "accumulation only" figure): with the
// virtual points' motion it keeps more of the sheets' contrast than with the surface G-buffer's, which is
// about zero for the air in front of the far wall. Measured at frames 4-5 with the history's a 0.5: -18%
// against -27%; at the bench's 192x108 with a 0.8, -17% against -36% at frame 4, and -2% with nothing moving
// (docs/denoising.md: a volumetric sheet's image changes under parallax in ways no motion vector reproduces).
// Catches: the volume motion not reaching the volume instance (its history reprojected with the surface
// motion: the two figures equal).
TEST(Shafts, AccumulationAloneKeepsMoreSheetsWithVolumeMotion) {
  auto floor = [](const json& j) {
    const json& f = j["contrast_error_accumulation_only_from_frame_4"];
    return f.contains("mean") ? f["mean"].get<double>() : std::nan("");
  };
  const double vp = floor(run(json(), true));
  const double surface = floor(run({{"denoise", {{"volume_motion", "surface"}}}}, true));
  std::cout << "sheet contrast of the accumulation alone / reference's - 1, frames 4-5: virtual point motion "
            << vp << ", surface motion " << surface << "\n";
  EXPECT_GT(vp - surface, 0.07);
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

// Issue 13's goal at the bench's size, 192x108 (a sheet 2-6 pixels wide), frames 0-5 against references of
// 128 spp x 4 volume samples: the sheets' contrast in the denoised volume term within 15% of the reference's
// from frame 4 on, and the volume's mean within 2%. The volume instance's defaults against the previous ones
// (the history's a 0.8, the history test's k 0.5, TAA's min/max clamp, no epipolar term) and against the
// defaults without the epipolar term, in the same run.
TEST(Shafts, SheetContrastWithinFifteenPercentAtTheBenchSize) {
  const json now = run(json(), false, 192, 108);
  const json previous = run({{"denoise",
                              {{"volume",
                                {{"accumulate", 0.8},
                                 {"history_test", 0.5},
                                 {"taa_clamp", "minmax"},
                                 {"taa_gamma", 1},
                                 {"epipolar", 0}}}}}},
                            false, 192, 108);
  const json flat = run({{"denoise", {{"volume", {{"epipolar", 0}}}}}}, false, 192, 108);
  auto contrast = [](const json& j, int f) {
    return j["per_frame"][f]["sheet_contrast"]["volume_over_reference"].get<double>() - 1;
  };
  auto worst_late = [&](const json& j) { return std::min(contrast(j, 4), contrast(j, 5)); };
  auto mean = [](const json& j) {
    double s = 0;
    for (int f = 0; f < 6; ++f)
      s += j["per_frame"][f]["mean_luminance_over_reference"]["volume"].get<double>();
    return s / 6;
  };
  std::cout << "sheet contrast error, worst of frames 4-5: defaults " << worst_late(now) << ", previous "
            << worst_late(previous) << ", without the epipolar term " << worst_late(flat) << "\n"
            << "sheet contrast error at frame 0: defaults " << contrast(now, 0)
            << ", without the epipolar term " << contrast(flat, 0) << "\n"
            << "volume mean error, frames 0-5: defaults " << mean(now) << ", previous " << mean(previous)
            << "\n";
  // The goals, measured -14.4% (frames 4-5) and -1.7% (at the bench's 256-spp references, -12.1% and -1.4%
  // over 8 frames). Catches: the defaults not reaching the volume instance (the previous ones: -21.6%).
  EXPECT_GT(worst_late(now), -0.15);
  EXPECT_LT(std::abs(mean(now)), 0.02);
  EXPECT_LT(worst_late(previous), -0.18);
  // The epipolar term keeps the sheets where the filter works alone, at frame 0: measured -8.0% against
  // -15.5%. Catches: the term not running (no light image reaching the filter, or its define missing).
  EXPECT_GT(contrast(now, 0) - contrast(flat, 0), 0.04);
  EXPECT_EQ(context().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze::test
