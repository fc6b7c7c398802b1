// Procedural volume specs: JSON parsing, validation and the analytic fields (no OpenVDB here).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <set>

#include "vdb/vdb.h"

namespace haze::vdb {
namespace {

// Integer hash (lowbias32) so that the noise is the same on every platform and compiler.
uint32_t hash32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}

// Lattice value in [-1, 1].
double lattice(int x, int y, int z, uint32_t seed) {
  uint32_t h = hash32(uint32_t(x) ^ hash32(uint32_t(y) ^ hash32(uint32_t(z) ^ hash32(seed))));
  return double(h) / 2147483647.5 - 1.0;
}

// Value noise: a smooth interpolation of lattice values, so it stays within [-1, 1] (the cloud's extent bound
// relies on that, which gradient noise would not guarantee).
double value_noise(glm::dvec3 p, uint32_t seed) {
  glm::dvec3 f = glm::floor(p);
  glm::ivec3 i(f);
  glm::dvec3 t = p - f;
  t = t * t * (3.0 - 2.0 * t);
  double c[2][2][2];
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b)
      for (int d = 0; d < 2; ++d) c[a][b][d] = lattice(i.x + a, i.y + b, i.z + d, seed);
  auto lerp = [](double u, double v, double w) { return u + (v - u) * w; };
  double x00 = lerp(c[0][0][0], c[1][0][0], t.x), x10 = lerp(c[0][1][0], c[1][1][0], t.x);
  double x01 = lerp(c[0][0][1], c[1][0][1], t.x), x11 = lerp(c[0][1][1], c[1][1][1], t.x);
  return lerp(lerp(x00, x10, t.y), lerp(x01, x11, t.y), t.z);
}

// Normalized fBm in [-1, 1].
double fbm(glm::dvec3 p, uint32_t seed, int octaves) {
  double sum = 0, norm = 0, amp = 1;
  for (int o = 0; o < octaves; ++o) {
    sum += amp * value_noise(p, seed + uint32_t(o) * 0x9e3779b9U);
    norm += amp;
    amp *= 0.5;
    p = p * 2.0 + glm::dvec3(17.3, -5.1, 9.7);  // offset so octaves do not share the lattice origin
  }
  return sum / norm;
}

double smoothstep(double e0, double e1, double x) {
  double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

glm::dvec3 read_vec3(const nlohmann::json& v, const std::string& where, const char* key, bool allow_scalar) {
  if (allow_scalar && v.is_number()) return glm::dvec3(v.get<double>());
  if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() || !v[2].is_number())
    throw Error(fmt::format("{}: key '{}' must be {}[x, y, z] of numbers, got {}", where, key,
                            allow_scalar ? "a number or " : "", v.dump()));
  return {v[0].get<double>(), v[1].get<double>(), v[2].get<double>()};
}

double read_number(const nlohmann::json& v, const std::string& where, const char* key) {
  if (!v.is_number()) throw Error(fmt::format("{}: key '{}' must be a number, got {}", where, key, v.dump()));
  return v.get<double>();
}

}  // namespace

void validate(const ProceduralSpec& s, const std::string& where) {
  auto bad = [&](const char* key, const std::string& why) {
    throw Error(fmt::format("{}: key '{}' {}", where, key, why));
  };
  auto finite3 = [](glm::dvec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
  if (s.kind != "box" && s.kind != "sphere" && s.kind != "cloud" && s.kind != "height_fog" &&
      s.kind != "ramp")
    bad("kind", fmt::format("is '{}'; use one of box, sphere, cloud, height_fog, ramp", s.kind));
  if (!(s.voxel_size > 0) || !std::isfinite(s.voxel_size))
    bad("voxel_size", fmt::format("must be > 0, got {}", s.voxel_size));
  if (!finite3(s.center)) bad("center", "must be finite");
  if (!finite3(s.size) || !(s.size.x > 0)) bad("size", "must be finite and > 0");
  bool round = s.kind == "sphere" || s.kind == "cloud";
  if (!round && !(s.size.y > 0 && s.size.z > 0)) bad("size", "must be > 0 on every axis");
  if (!(s.density > 0) || !std::isfinite(s.density))
    bad("density", fmt::format("must be > 0, got {}", s.density));
  if (s.kind == "height_fog" && !(s.falloff > 0 && std::isfinite(s.falloff)))
    bad("falloff", fmt::format("is the scale height of height_fog and must be > 0, got {}", s.falloff));
  if (s.kind == "cloud" && !(s.falloff >= 0 && s.falloff <= 1))
    bad("falloff", fmt::format("is the cloud's noise amplitude and must be in [0, 1], got {}", s.falloff));
  if (!(s.frequency > 0) || !std::isfinite(s.frequency))
    bad("frequency", fmt::format("must be > 0, got {}", s.frequency));
  if (s.octaves < 1 || s.octaves > 16) bad("octaves", fmt::format("must be in [1, 16], got {}", s.octaves));
  if (round && s.size.x / 2 < 2 * s.voxel_size)
    bad("voxel_size", fmt::format("must be at most a quarter of the diameter size.x = {}", s.size.x));
  // Voxel count of the generated extent; the dense fills cost 4 bytes per voxel.
  glm::dvec3 extent = round ? glm::dvec3(s.size.x * (1 + (s.kind == "cloud" ? s.falloff : 0))) : s.size;
  glm::dvec3 n = extent / s.voxel_size + 2.0;
  double voxels = n.x * n.y * n.z;
  if (voxels > double(1u << 27))
    bad("voxel_size", fmt::format("gives {:.3g} voxels (limit {:.3g}); raise voxel_size or shrink size",
                                  voxels, double(1u << 27)));
  // OpenVDB's index coordinates are 32-bit: the grid must lie within +-2^30 voxels of the origin (and index
  // positions must stay exact in the float of the shaders' world-to-index transform).
  const glm::dvec3 far = glm::abs(s.center) + extent * 0.5;
  const double reach = std::max({far.x, far.y, far.z}) / s.voxel_size;
  if (reach > double(1 << 30))
    bad("center",
        fmt::format("puts the grid {:.3g} voxels from the origin (limit {:.3g} = 2^30); move the medium "
                    "with its transform instead, or raise voxel_size",
                    reach, double(1 << 30)));
}

ProceduralSpec procedural_from_json(const nlohmann::json& j, const std::string& where) {
  if (!j.is_object())
    throw Error(fmt::format("{}: procedural volume must be a JSON object, got {}", where, j.dump()));
  ProceduralSpec s;
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string& k = it.key();
    const nlohmann::json& v = it.value();
    if (k == "kind") {
      if (!v.is_string())
        throw Error(fmt::format("{}: key 'kind' must be a string, got {}", where, v.dump()));
      s.kind = v.get<std::string>();
    } else if (k == "voxel_size") {
      s.voxel_size = read_number(v, where, "voxel_size");
    } else if (k == "center") {
      s.center = read_vec3(v, where, "center", false);
    } else if (k == "size") {
      s.size = read_vec3(v, where, "size", true);
    } else if (k == "density") {
      s.density = read_number(v, where, "density");
    } else if (k == "falloff") {
      s.falloff = read_number(v, where, "falloff");
    } else if (k == "frequency") {
      s.frequency = read_number(v, where, "frequency");
    } else if (k == "seed") {
      if (!v.is_number_integer() || v.get<int64_t>() < 0 || v.get<int64_t>() > int64_t(UINT32_MAX))
        throw Error(fmt::format("{}: key 'seed' must be an integer in [0, 2^32), got {}", where, v.dump()));
      s.seed = uint32_t(v.get<int64_t>());
    } else if (k == "octaves") {
      if (!v.is_number_integer())
        throw Error(fmt::format("{}: key 'octaves' must be an integer, got {}", where, v.dump()));
      s.octaves = int(std::clamp<int64_t>(v.get<int64_t>(), -1, 1000));
    } else {
      throw Error(
          fmt::format("{}: unknown key '{}' (known: kind, voxel_size, center, size, density, falloff, "
                      "frequency, seed, octaves)",
                      where, k));
    }
  }
  validate(s, where);
  return s;
}

nlohmann::json to_json(const ProceduralSpec& s) {
  return {{"kind", s.kind},
          {"voxel_size", s.voxel_size},
          {"center", {s.center.x, s.center.y, s.center.z}},
          {"size", {s.size.x, s.size.y, s.size.z}},
          {"density", s.density},
          {"falloff", s.falloff},
          {"frequency", s.frequency},
          {"seed", s.seed},
          {"octaves", s.octaves}};
}

double procedural_value(const ProceduralSpec& s, glm::dvec3 p) {
  glm::dvec3 d = p - s.center;
  if (s.kind == "box") {
    glm::dvec3 h = s.size * 0.5;
    return (std::abs(d.x) <= h.x && std::abs(d.y) <= h.y && std::abs(d.z) <= h.z) ? s.density : 0.0;
  }
  if (s.kind == "sphere") return glm::length(d) <= s.size.x * 0.5 ? s.density : 0.0;
  if (s.kind == "ramp") {
    // Linear in y, 0 at the bottom face to `density` at the top: trilinear interpolation reproduces it
    // exactly, which gives transmittance tests a closed form.
    glm::dvec3 h = s.size * 0.5;
    if (std::abs(d.x) > h.x || std::abs(d.y) > h.y || std::abs(d.z) > h.z) return 0.0;
    return s.density * (d.y + h.y) / s.size.y;
  }
  if (s.kind == "height_fog") {
    glm::dvec3 h = s.size * 0.5;
    if (std::abs(d.x) > h.x || std::abs(d.y) > h.y || std::abs(d.z) > h.z) return 0.0;
    return s.density * std::exp(-(d.y + h.y) / s.falloff);
  }
  if (s.kind == "cloud") {
    // Dense core, noisy edge: coverage drops from 1 at the centre to 0 at the radius, displaced by the noise;
    // |noise| <= 1 keeps the cloud within radius * (1 + amplitude), and the peak is `density`.
    double r = glm::length(d) / (s.size.x * 0.5);
    if (r > 1 + s.falloff) return 0.0;
    double n = s.falloff > 0 ? fbm(p * s.frequency, s.seed, s.octaves) : 0.0;
    return s.density * smoothstep(0.0, 0.5, 1.0 - r + s.falloff * n);
  }
  return 0.0;
}

}  // namespace haze::vdb
