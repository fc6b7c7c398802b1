// shaders/surfaces/bvh_layout.glsl compiled as C++ with GLM: the host fills the very structs the shaders
// read (one source of truth for the BVH and ray/hit layouts).
#pragma once

#include <glm/glm.hpp>

namespace haze::glsl {
using namespace glm;
using uint = glm::uint;
#include "shaders/surfaces/bvh_layout.glsl"

static_assert(sizeof(GpuBvhNode) == 32 && sizeof(GpuTriangle) == 48 && sizeof(GpuTriangleUv) == 32 &&
              sizeof(GpuTriangleNormals) == 16);
static_assert(sizeof(GpuRay) == 32 && sizeof(GpuRayHit) == 48);
}  // namespace haze::glsl
