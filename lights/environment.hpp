// Environment maps: latitude-longitude radiance images (OpenEXR, Radiance HDR, PNG), the piecewise-constant
// distribution that importance-samples them (shaders/lights/lights.glsl), and a generated sky for tests and
// demos.
//
// Orientation: pixel (i, j) of a W x H map covers u = x / W in [i / W, (i + 1) / W) and v = y / H in
// [j / H, (j + 1) / H), rows from the top. theta = pi v is the angle from +y (the top row looks up) and
// phi = 2 pi u, and the direction is (-sin phi sin theta, cos theta, cos phi sin theta): the image centre
// looks along -z (where the default camera looks), the quarter to its right along +x, the left and right
// edges along +z. lights.environment.rotate turns the map by that many degrees about +y. Radiance is
// constant over a pixel (nearest lookup).
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <stdexcept>
#include <string>
#include <vector>

namespace haze::lights {

// The shaders' uniform numbers are multiples of 2^-24 (common/rng.glsl): the CDFs and the light choice are
// fixed point with that unit, so what the shaders sample is exactly what the tables say.
inline constexpr uint64_t kRandomOne = uint64_t(1) << 24;

// Errors of the lights part: one line naming the key and file.
struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct EnvironmentMap {
  uint32_t width = 0, height = 0;
  std::vector<glm::vec3> texels;  // linear RGB radiance, rows from the top, x fastest
  // Texel channels that were replaced by 0 on reading, by kind.
  uint64_t nan = 0, inf = 0, negative = 0;
  uint64_t replaced() const { return nan + inf + negative; }
};

// Reads a map: OpenEXR (channels R, G, B; Y for grey; Y, RY, BY luminance-chroma; half or float), Radiance
// .hdr, or 8/16-bit PNG (and what else stb_image reads: JPEG, TGA, ...) decoded from sRGB. NaN, infinite and
// negative channel values are replaced by 0 and counted. Throws Error (one line naming `key` and the file)
// for a missing, unreadable or undecodable file, missing channels, an empty image or one over 2^26 texels.
EnvironmentMap read_environment_map(const std::string& path,
                                    const std::string& key = "lights.environment.file");

// The checks of read_environment_map that need only the file's header (existence, format, size, channels),
// for refusing a bad map before the device starts.
void check_environment_map(const std::string& path, const std::string& key = "lights.environment.file");

// Writes a map as OpenEXR (.exr, float RGB) or Radiance HDR (.hdr), to a temporary renamed into place.
void write_environment_map(const std::string& path, const EnvironmentMap& map);

// A clear-sky stand-in generated in closed form: a horizon-to-zenith blue gradient, a brown ground, and a
// sun disc of `sun_radiance` (about 1e4 x the sky) `sun_size` degrees across at the given elevation and
// azimuth (degrees; azimuth 0 is -z, 90 is +x).
struct SkyParams {
  uint32_t width = 256, height = 128;
  float sun_elevation = 35.f, sun_azimuth = 30.f, sun_size = 4.f;
  float sun_radiance = 2000.f;
  glm::vec3 zenith{0.10f, 0.22f, 0.55f}, horizon{0.55f, 0.65f, 0.80f}, ground{0.12f, 0.09f, 0.06f};
};
EnvironmentMap make_sky(const SkyParams& p);

// Importance sampling of a map: pixel (i, j) is drawn with probability proportional to its luminance
// times sin(theta) at the row's centre (its solid angle), then (u, v) uniformly inside it, so the density
// over the sphere is p(u, v) / (2 pi^2 sin theta). The CDFs are fixed point with 24 bits (the resolution
// of the shaders' random numbers), stored as floats: a pixel's probability is exactly the difference of
// two entries, and every pixel with radiance keeps at least 2^-24 of its row (every such row of the
// marginal), so no texel is out of the sampler's reach.
struct EnvironmentDistribution {
  uint32_t width = 0, height = 0;
  std::vector<float> conditional;  // width * height: per row, the CDF at each pixel's right edge
  std::vector<float> marginal;     // height: the CDF at each row's lower edge
  glm::dvec3 integral{0};          // integral of the radiance over the sphere, per channel
  double luminance_integral = 0;   // the same of the luminance
};
EnvironmentDistribution build_distribution(const EnvironmentMap& map);

// Solid angle of a pixel in row j of a map H rows high and W wide.
double texel_solid_angle(uint32_t j, uint32_t width, uint32_t height);

}  // namespace haze::lights
