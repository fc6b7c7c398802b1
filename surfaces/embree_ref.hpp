#pragma once
// Embree's own scene and intersector over world-space triangles: the CPU reference for the shaders' BVH
// traversal (tests) and the baseline for benchmarks.

#include <cstdint>
#include <glm/glm.hpp>
#include <span>
#include <vector>

#include "surfaces/bvh_layout.hpp"

struct RTCDeviceTy;
struct RTCSceneTy;

namespace haze::surfaces {

struct RefHit {
  float t = 0;                         // tmax on a miss
  uint32_t triangle = glsl::BVH_NONE;  // input index (GpuTriangle v2.w), BVH_NONE on a miss
  uint32_t instance = glsl::BVH_NONE;
  uint32_t primitive = glsl::BVH_NONE;
  glm::vec2 uv{0};      // p = (1 - u - v) v0 + u v1 + v v2
  glm::vec3 normal{0};  // unit geometric normal, normalize(cross(v1 - v0, v2 - v0)), as the shader's
  bool hit() const { return triangle != glsl::BVH_NONE; }
};

// Thread-safe queries after construction. Rays follow the shader's rules: hits in (tmin, tmax); a ray
// with a non-finite origin, direction or tmin, a NaN tmax, tmin > tmax, or a largest direction component
// outside [1e-30, 1e30] misses. (Embree itself loses hits far below that: directions of length ~1e-19.)
class EmbreeScene {
 public:
  // Triangles in any order (world_triangles() or a Bvh's leaf order); ids come from their w components.
  explicit EmbreeScene(std::span<const glsl::GpuTriangle> triangles);
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  RefHit intersect(glm::vec3 origin, glm::vec3 direction, float tmin, float tmax) const;
  bool occluded(glm::vec3 origin, glm::vec3 direction, float tmin, float tmax) const;

 private:
  RTCDeviceTy* device_ = nullptr;
  RTCSceneTy* scene_ = nullptr;
  std::vector<glsl::GpuTriangle> triangles_;  // by Embree primID
};

}  // namespace haze::surfaces
