#include "surfaces/texture.hpp"

#include <fmt/format.h>
#include <stb/stb_image.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <glm/gtc/packing.hpp>
#include <memory>

#include "gpu/error.hpp"
#include "shaders/glsl.hpp"

namespace haze::surfaces {

namespace {

constexpr size_t kMaxTexels = size_t(1) << 26;

template <class T>
using StbImage = std::unique_ptr<T, decltype(&stbi_image_free)>;

}  // namespace

Texture load_texture(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::exists(path, ec) && !std::filesystem::is_regular_file(path, ec))
    throw Error(
        fmt::format("texture {}: not a regular file (a directory, device, pipe or socket); name an image "
                    "file",
                    path));
  if (!std::filesystem::is_regular_file(path, ec))
    throw Error(fmt::format("texture {}: no such file; check the path", path));  // the scene resolved it
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw Error(fmt::format("texture {}: cannot open: {}", path, std::strerror(errno)));
  std::unique_ptr<FILE, decltype(&std::fclose)> file(f, &std::fclose);

  int w = 0, h = 0, n = 0;
  if (!stbi_info_from_file(f, &w, &h, &n))
    throw Error(fmt::format("texture {}: cannot decode ({}); use PNG, JPEG, TGA, BMP, PSD, GIF, PNM or HDR",
                            path, gpu::printable(stbi_failure_reason())));
  if (size_t(w) * size_t(h) > kMaxTexels)
    throw Error(fmt::format("texture {}: {}x{} is over 2^26 texels; scale it down", path, w, h));

  Texture t;
  t.width = uint32_t(w);
  t.height = uint32_t(h);
  t.texels.resize(size_t(w) * h);
  const size_t count = t.texels.size() * 3;
  auto fill = [&](auto* data, auto decode) {
    if (!data)
      throw Error(fmt::format("texture {}: cannot decode ({}); the file may be truncated", path,
                              gpu::printable(stbi_failure_reason())));
    for (size_t i = 0; i < count; ++i) t.texels[i / 3][int(i % 3)] = decode(data[i]);
  };
  if (stbi_is_hdr_from_file(f)) {
    StbImage<float> data(stbi_loadf_from_file(f, &w, &h, &n, 3), &stbi_image_free);
    fill(data.get(), [](float v) { return v; });
  } else if (stbi_is_16_bit_from_file(f)) {
    StbImage<stbi_us> data(stbi_load_from_file_16(f, &w, &h, &n, 3), &stbi_image_free);
    fill(data.get(), [](stbi_us v) { return glsl::srgb_decode(float(v) / 65535.0f); });
  } else {
    StbImage<stbi_uc> data(stbi_load_from_file(f, &w, &h, &n, 3), &stbi_image_free);
    fill(data.get(), [](stbi_uc v) { return glsl::srgb_decode(float(v) / 255.0f); });
  }
  for (size_t i = 0; i < t.texels.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      float v = t.texels[i][c];
      if (!(v >= 0.0f && v <= 1.0f))
        throw Error(
            fmt::format("texture {}: texel ({}, {}) has value {}; an albedo texture holds values in "
                        "[0, 1] (scale the image, or use \"albedo\" for the tint)",
                        path, i % t.width, i / t.width, v));
    }
  return t;
}

void pack_texels(const Texture& t, std::vector<glm::uvec2>& out) {
  out.reserve(out.size() + t.texels.size());
  for (const glm::vec3& c : t.texels)
    out.emplace_back(glm::packUnorm2x16(glm::vec2(c.r, c.g)), glm::packUnorm2x16(glm::vec2(c.b, 0.0f)));
}

}  // namespace haze::surfaces
