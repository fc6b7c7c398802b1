// The scene's lights on the device: point and spot lights, the sun, the environment and emissive
// triangles in one list (shaders/lights/lights.glsl samples it for next-event estimation), each entry with
// its probability of being chosen (an alias table over estimated power, or uniform). A light type is a
// feature: a scene without it compiles no code for it, a scene without lights has no light buffer, and only
// an environment map has the map's buffers.
#pragma once

#include <cfloat>
#include <cstdint>
#include <glm/glm.hpp>
#include <optional>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "lights/environment.hpp"
#include "scene/scene.hpp"
#include "shaders/glsl.hpp"

namespace haze::lights {

// An emissive surface triangle (two-sided), in world space.
struct Emitter {
  glm::vec3 v0, v1, v2;
  glm::vec3 radiance;
};

// A world box around what the camera may see (the renderer's camera, media and surfaces); the lights add
// their positions. Distant lights are weighed by their flux through the disc of its bounding sphere.
struct Bounds {
  glm::vec3 lo{FLT_MAX}, hi{-FLT_MAX};
  void add(glm::vec3 p) {
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
  bool empty() const { return lo.x > hi.x; }
  // Radius of the bounding sphere; 1 for an empty box or a single point (only the ratio between local and
  // distant lights depends on it).
  double radius() const;
};

// Local lights first (equi-angular sampling walks the first `local` entries), then emissive triangles,
// then the sun, then the environment (always last: background() reads its entry). The w components of
// radiance, direction and params hold the choice (apply_choice). `map` describes an environment map.
std::vector<glsl::GpuLight> light_list(const scene::Lights& l, const std::vector<Emitter>& emitters,
                                       const EnvironmentDistribution* map = nullptr);

// Estimated power of each entry, in luminance: points 4 pi I, spots I times the solid angle of their cone
// (the smooth falloff counted at half), emissive triangles 2 pi L A (two-sided), the sun E pi r^2 and the
// environment pi r^2 times the integral of its radiance over the sphere (r: `radius`, the scene's bounding
// sphere). `env_integral` is that integral (4 pi L for a constant environment).
std::vector<double> light_powers(const std::vector<glsl::GpuLight>& list, double env_integral, double radius);

// Vose's alias table over `weights` (all zero: uniform), as the shader's light_choose() reads it: with U
// the 24 random bits of u, slot s = floor(U n / 2^24) keeps s when (U n mod 2^24) < threshold[s], else
// takes alias[s]. pmf is the exact probability of each light under that rule (it sums to 1); every light of
// positive weight keeps at least one value of U.
struct AliasTable {
  std::vector<uint32_t> threshold, alias;
  std::vector<double> pmf;
};
AliasTable alias_table(const std::vector<double>& weights);

// Writes the table into the list: radiance.w = pmf, direction.w = threshold, params.w = alias.
void apply_choice(std::vector<glsl::GpuLight>& list, const AliasTable& t);

class Lights : public gpu::DeviceData {
 public:
  explicit Lights(gpu::Context& ctx) : ctx_(ctx) {}

  // Rebuilds the list for the scene's lights and the surfaces' emitters; the buffer is reused when its size
  // is unchanged and dropped when the scene has no light. An environment map is read again only when its
  // file (path, size or modification time) changed. `bounds`: see Bounds.
  void update(const scene::Lights& l, const std::vector<Emitter>& emitters, const Bounds& bounds = {});

  bool any() const { return !list_.empty(); }
  size_t count() const { return list_.size(); }
  size_t local_count() const { return local_; }  // point and spot lights
  bool has_local() const { return local_ > 0; }
  bool has_environment() const { return scene_.environment.has_value(); }
  bool has_area() const { return area_; }  // emissive triangles
  const std::vector<glsl::GpuLight>& list() const { return list_; }
  const std::vector<double>& powers() const { return powers_; }
  const AliasTable& choice() const { return choice_; }
  bool has_map() const { return map_.has_value(); }
  const EnvironmentDistribution* map_distribution() const { return map_ ? &map_->distribution : nullptr; }
  int map_reads() const { return map_reads_; }  // how often a map file was read
  std::vector<std::string> notes() const;       // texels replaced on reading the map

  // HAZE_SUN, HAZE_ENV (and HAZE_ENV_MAP), HAZE_LOCAL, HAZE_AREA for the types present; the bindings
  // "lights" and, for a map, "env_texels", "env_conditional", "env_marginal".
  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
  // counts.y (lights), counts.z (local lights), the constant environment and the sun's visible disk.
  void fill(glsl::GpuScene& g) const;

 private:
  struct Map {
    std::string path;
    uintmax_t bytes = 0;
    int64_t mtime = 0;
    EnvironmentDistribution distribution;
    std::string note;
    gpu::Buffer texels, conditional, marginal;
  };
  void keep_map(const std::string& path);

  gpu::Context& ctx_;
  scene::Lights scene_;
  std::vector<glsl::GpuLight> list_;
  std::vector<double> powers_;
  AliasTable choice_;
  size_t local_ = 0;
  bool area_ = false;
  gpu::Buffer buffer_;
  std::optional<Map> map_;
  int map_reads_ = 0;
};

}  // namespace haze::lights
