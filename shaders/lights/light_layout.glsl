// The light list as the shaders read it, shared with the host (lights/lights.hpp includes this with GLM).
// Only vec4 members: std430 and C++ then have the same layout.
#ifndef HAZE_LIGHT_LAYOUT_GLSL
#define HAZE_LIGHT_LAYOUT_GLSL

// Light types in GpuLight.position.w. Local lights come first in the light array (equi-angular sampling
// walks the first GpuScene.counts.z entries).
const uint LIGHT_POINT = 0u;  // point and spot (a point is a spot with no falloff)
const uint LIGHT_SUN = 1u;
const uint LIGHT_ENV = 2u;
const uint LIGHT_TRIANGLE = 3u;  // an emissive surface triangle (two-sided)

struct GpuLight {
  vec4 position;   // xyz position (local), w: type
  vec4 radiance;   // rgb: intensity (local), irradiance (sun), radiance (env)
  vec4 direction;  // xyz: spot axis (local), direction towards the sun
  vec4 params;     // local: x cos_outer, y cos_inner of the spot falloff; sun: x cos of the half angle
};

#endif
