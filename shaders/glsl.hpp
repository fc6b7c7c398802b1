// The GLSL headers of shaders/common compiled as C++ with GLM: the CPU tests and the host call the very
// functions the shaders run (one source of truth for sampling, phase functions, colour and layouts).
#pragma once

#include <cmath>
#include <glm/glm.hpp>

namespace haze::glsl {
using namespace glm;
using uint = glm::uint;
#include "shaders/common/camera.glsl"
#include "shaders/common/color.glsl"
#include "shaders/common/compat.glsl"
#include "shaders/common/packing.glsl"
#include "shaders/common/rng.glsl"
#include "shaders/common/sampling.glsl"
#include "shaders/guiding/guide.glsl"
#include "shaders/guiding/volume_motion_layout.glsl"
#include "shaders/lights/light_layout.glsl"
#include "shaders/surfaces/bvh_layout.glsl"
#include "shaders/volume/gpu_scene.glsl"
#include "shaders/volume/walk_splits_layout.glsl"
}  // namespace haze::glsl
