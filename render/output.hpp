// Writing results: multi-layer EXR, PNG preview and JSON, each to a temporary file renamed into place so
// that nothing already written is lost or half-overwritten.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
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

// Every present layer's channels by name ("R", "volume.R", ...) with their planes, in exr_layers() order.
std::vector<std::pair<std::string, std::vector<float>>> exr_planes(const Image& img);
void write_exr(const std::string& path, const Image& img);
void write_png(const std::string& path, const Image& img);
// Float channels by name ("denoised.R", ...), each width * height values; written atomically. `epipole`: the
// header attribute haze.epipole (v3f), the frame's light_epipole(), which `haze denoise` passes on.
void write_exr_channels(const std::string& path, int width, int height,
                        const std::vector<std::pair<std::string, const std::vector<float>*>>& channels,
                        const std::optional<glm::vec3>& epipole = std::nullopt);
// Packed RGBA8 pixels (red in the low byte, as the preview buffer holds them) written as an 8-bit RGB PNG:
// the alpha is always 255, and tools that montage previews (oiiotool) expect three channels.
void write_png_rgb8(const std::string& path, int width, int height, const std::vector<uint32_t>& rgba);
// The preview of linear RGB values (3 floats per pixel) as haze's PNGs make it: exposure in EV, then the
// tone curve `tonemap` (aces, reinhard, clamp; render.tonemap), then sRGB. Packed as write_png_rgb8 takes.
std::vector<uint32_t> preview_srgb8(const std::vector<float>& rgb, float exposure,
                                    const std::string& tonemap);
void write_json(const std::string& path, const nlohmann::json& j);
void write_text(const std::string& path, const std::string& text);

// Creates dir if needed and checks that a file can be created in it; throws a one-line Error otherwise.
void ensure_writable_dir(const std::string& dir);

// The outputs of one run, all or nothing. stage(target) gives the path a writer writes instead of the
// target: a hidden temporary beside it (".NAME.tmp<pid>"). commit() renames every staged file onto its
// target, in staging order; a run that fails before commit() leaves the folder's earlier outputs as they
// were, and its temporaries are removed (by the destructor, or, after a kill, by the next run in the
// folder, which removes the temporaries of processes that no longer exist).
class OutputSet {
 public:
  explicit OutputSet(std::string dir);
  ~OutputSet();
  OutputSet(const OutputSet&) = delete;
  OutputSet& operator=(const OutputSet&) = delete;

  // Refuses a target `name` (in dir()) that is a directory: call it for every output before rendering.
  void check(const std::string& name) const;
  // check(), then the path to write instead of the target.
  std::string stage(const std::string& name);
  void commit();
  const std::string& dir() const { return dir_; }

 private:
  std::string dir_;
  std::vector<std::pair<std::string, std::string>> staged_;  // (staging path, target)
  bool committed_ = false;
};

// Reads a float EXR's channels by name (for tests and `haze compare`). Missing channel -> Error.
struct ExrImage {
  int width = 0, height = 0;
  std::vector<std::string> channels;
  std::vector<std::vector<float>> data;  // one plane per channel
  std::optional<glm::vec3> epipole;      // the header's haze.epipole, where present
  const std::vector<float>& channel(const std::string& name) const;
};
ExrImage read_exr(const std::string& path);

}  // namespace haze::render
