#pragma once
// Albedo textures: images read with stb_image into linear RGB, packed for the shaders
// (shaders/surfaces/material.glsl filters them).

#include <cstdint>
#include <glm/glm.hpp>
#include <string>
#include <vector>

#include "surfaces/error.hpp"

namespace haze::surfaces {

struct Texture {
  uint32_t width = 0, height = 0;
  std::vector<glm::vec3> texels;  // linear RGB in [0, 1], rows from the top of the image
  glm::vec3 at(uint32_t x, uint32_t y) const { return texels[size_t(y) * width + x]; }
};

// Reads PNG, JPEG, TGA, BMP, PSD, GIF, PNM or Radiance HDR. 8- and 16-bit images are sRGB-encoded and
// decoded to linear; HDR images are linear. Alpha is ignored. Throws Error (one line naming the file) for
// a missing or undecodable file, an image over 2^26 texels, or a texel outside [0, 1] or NaN (an albedo
// reflects at most what arrives).
Texture load_texture(const std::string& path);

// Texels as two packUnorm2x16 words each (r g, b 0): 16-bit linear, what texture_texel() unpacks.
void pack_texels(const Texture& t, std::vector<glm::uvec2>& out);

}  // namespace haze::surfaces
