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

// The w components of radiance, direction and params are the light choice (lights/lights.hpp,
// alias_table): the probability of choosing this entry, its slot's threshold and alias.
struct GpuLight {
  vec4 position;   // xyz position (local), first corner (triangle); w: type
  vec4 radiance;   // rgb: intensity (local), radiance (triangle), irradiance (sun), radiance or, for a map,
                   // its intensity (env); w: probability of choosing this light
  vec4 direction;  // xyz: spot axis (local), second corner (triangle), direction towards the sun; env map:
                   // x, y cosine and sine of the turn about +y; w: the slot's threshold (of 2^24)
  vec4 params;     // local: x cos_outer, y cos_inner of the spot falloff; triangle: xyz third corner; sun:
                   // x cos of the half angle; env map: x, y width and height; w: the slot's alias
};

#endif
