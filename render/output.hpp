// Writing results: multi-layer EXR, PNG preview and JSON, each to a temporary file renamed into place so
// that nothing already written is lost or half-overwritten.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "render/renderer.hpp"

namespace haze::render {

struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// One EXR layer: its channel names and how each channel's value is read from an Image.
struct Layer {
  std::string name;                   // "" for the final image (R, G, B)
  std::vector<std::string> channels;  // e.g. {"R","G","B"}
  std::function<float(const Image&, size_t pixel, int channel)> value;
  std::function<bool(const Image&)> present = [](const Image&) { return true; };  // written only then
};
const std::vector<Layer>& exr_layers();

void write_exr(const std::string& path, const Image& img);
void write_png(const std::string& path, const Image& img);
// Float channels by name ("denoised.R", ...), each width * height values; written atomically.
void write_exr_channels(const std::string& path, int width, int height,
                        const std::vector<std::pair<std::string, const std::vector<float>*>>& channels);
void write_png_rgba8(const std::string& path, int width, int height, const std::vector<uint32_t>& rgba);
void write_json(const std::string& path, const nlohmann::json& j);
void write_text(const std::string& path, const std::string& text);

// Creates dir if needed and checks that a file can be created in it; throws a one-line Error otherwise.
void ensure_writable_dir(const std::string& dir);

// Reads a float EXR's channels by name (for tests and `haze compare`). Missing channel -> Error.
struct ExrImage {
  int width = 0, height = 0;
  std::vector<std::string> channels;
  std::vector<std::vector<float>> data;  // one plane per channel
  const std::vector<float>& channel(const std::string& name) const;
};
ExrImage read_exr(const std::string& path);

}  // namespace haze::render
