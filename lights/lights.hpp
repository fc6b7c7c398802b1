// The scene's lights on the device: point and spot lights, the sun, the environment and emissive
// triangles in one list (shaders/lights/lights.glsl samples it for next-event estimation). A light type is
// a feature: a scene without it compiles no code for it, and a scene without lights has no light buffer.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <vector>

#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "scene/scene.hpp"
#include "shaders/glsl.hpp"

namespace haze::lights {

// An emissive surface triangle (two-sided), in world space.
struct Emitter {
  glm::vec3 v0, v1, v2;
  glm::vec3 radiance;
};

// Local lights first (equi-angular sampling walks the first `local` entries), then emissive triangles,
// then the sun, then the environment.
std::vector<glsl::GpuLight> light_list(const scene::Lights& l, const std::vector<Emitter>& emitters);

class Lights : public gpu::DeviceData {
 public:
  explicit Lights(gpu::Context& ctx) : ctx_(ctx) {}

  // Rebuilds the list for the scene's lights and the surfaces' emitters; the buffer is reused when its size
  // is unchanged and dropped when the scene has no light.
  void update(const scene::Lights& l, const std::vector<Emitter>& emitters);

  bool any() const { return !list_.empty(); }
  size_t count() const { return list_.size(); }
  size_t local_count() const { return local_; }  // point and spot lights
  bool has_local() const { return local_ > 0; }
  const std::vector<glsl::GpuLight>& list() const { return list_; }

  // HAZE_SUN, HAZE_ENV, HAZE_LOCAL, HAZE_AREA for the types present; the binding "lights".
  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
  // counts.y (lights), counts.z (local lights), the environment and the sun's visible disk.
  void fill(glsl::GpuScene& g) const;

 private:
  gpu::Context& ctx_;
  scene::Lights scene_;
  std::vector<glsl::GpuLight> list_;
  size_t local_ = 0;
  bool area_ = false;
  gpu::Buffer buffer_;
};

}  // namespace haze::lights
