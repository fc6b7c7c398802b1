// `haze compare`: error metrics (relMSE, SMAPE, MSE, PSNR, FLIP) of a test image against a reference, or of a
// test sequence against a reference sequence (folders of EXR frames, matched in name order) with the
// temporal-stability measure.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "eval/metrics.hpp"

namespace haze::eval {

// One layer of an EXR file, its channels interleaved per pixel in haze's order (R, G, B; X, Y, Z).
struct LayerImage {
  int width = 0, height = 0;
  std::vector<std::string> channels;
  std::vector<float> data;
  Channels view() const {
    uint32_t n = uint32_t(channels.size());
    return {data.data(), size_t(width) * height, n, 0, n};
  }
};
// layer: "" for R, G, B, else the channels "<layer>.*". Throws a one-line Error for a missing file or
// layer, and for NaN or Inf when require_finite.
LayerImage read_layer(const std::string& path, const std::string& layer, bool require_finite = true);

// relMSE, SMAPE, MSE, PSNR, FLIP LDR and HDR of test against ref: the one place both `haze compare` and
// sweeps compute them. Keys relmse, smape, mse, psnr ("inf" when identical), flip_ldr, flip_hdr (null for
// a 2-channel layer, where FLIP has no meaning). LDR-FLIP sees the linear values clamped to [0, 1].
nlohmann::json image_metrics(const Channels& test, const Channels& ref, int width, int height);

// {"test": test_layer, "reference": ref_layer}: what results and reports record of a comparison, so that
// both sides are named (haze compares a layer with the same layer only; a test checks they agree).
nlohmann::json compared_layers(const std::string& test_layer, const std::string& ref_layer);
// "R, G, B" or "layer NAME", and for a comparison record "test layer X, reference layer Y".
std::string layer_name(const std::string& layer);
std::string layers_text(const nlohmann::json& layers);

// ref and test: both .exr files or both folders. layer: "" for R, G, B; else the channels "<layer>.*".
// Throws a one-line Error naming the file and what to do for a missing file, layer or frame, a size
// mismatch or non-finite values. flip_map: if not empty, the per-pixel FLIP maps are written there: for
// two images PATH.exr (channels flip_hdr.Y, flip_ldr.Y) and PATH.png (HDR-FLIP through magma); for two
// folders the folder PATH with <frame>.exr and <frame>.png per frame.
nlohmann::json compare_paths(const std::string& ref, const std::string& test, const std::string& layer,
                             const std::string& flip_map = "");

// `haze tonemap`: one layer of an EXR as an RGB PNG, through render::preview_srgb8 (3 channels as they are,
// 1 as grey, 2 as red and green). exposure / tonemap: NaN / "" take the scene's render.exposure and
// render.tonemap from a stats.json beside `in`, else 0 EV and aces. Non-finite values are drawn black and
// counted. Returns the line to print.
std::string tonemap_exr(const std::string& in, const std::string& layer, double exposure,
                        const std::string& tonemap, const std::string& out);

// One line per image (or frame) and the means, for the terminal.
std::string format_comparison(const nlohmann::json& j);

}  // namespace haze::eval
