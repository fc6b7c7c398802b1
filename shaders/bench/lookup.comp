#version 460
// Density lookups per second: each invocation evaluates sigma_t (trilinear PNanoVDB) at random points
// inside the majorant bounds, through the same code the tracker uses.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 64) in;
#include "common/dispatch.glsl"
#define HAZE_HETERO 1
#include "common/color.glsl"
#include "common/compat.glsl"
#include "common/rng.glsl"
#include "common/sampling.glsl"
#include "volume/gpu_scene.glsl"
layout(std430, binding = BINDING_result) writeonly buffer OutBuffer {
  float result[];
};
layout(push_constant) uniform Push {
  uint count;
  uint lookups;
}
pc;
#include "volume/medium.glsl"

void main() {
  uint i = invocation_index();
  if (i >= pc.count) return;
  uint rng = rng_init(7u, i, 0u);
  float sum = 0.0f;
  for (uint k = 0u; k < pc.lookups; ++k) {
    vec3 u = vec3(rng_next(rng), rng_next(rng), rng_next(rng));
    sum += sample_medium(mix(scene.maj_min.xyz, scene.maj_max.xyz, u), 0.5f, 0.5f).sigma_t;
  }
  result[i] = sum;
}
