// `haze compare`: error metrics of a test image against a reference, or of a test sequence against a
// reference sequence (folders of EXR frames, matched in name order) with the temporal-stability measure.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

namespace haze::render {

// ref and test: both .exr files or both folders. layer: "" for R, G, B; else the channels "<layer>.*".
// Throws a one-line Error naming the file and what to do for a missing file, layer or frame, a size
// mismatch or non-finite values.
nlohmann::json compare_paths(const std::string& ref, const std::string& test, const std::string& layer);

// One line per image (or frame) and the means, for the terminal.
std::string format_comparison(const nlohmann::json& j);

}  // namespace haze::render
