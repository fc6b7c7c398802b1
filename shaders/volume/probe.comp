#version 460
// sigma_t at given world points, through the tracker's own sample_medium (volume/medium.glsl): what the
// tests compare with NanoVDB's CPU sampler. One invocation per point; points[i].xyz in, sigma[i] out.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 64) in;
#include "common/color.glsl"
#include "common/compat.glsl"
#include "common/dispatch.glsl"
#include "common/rng.glsl"
#include "common/sampling.glsl"
#include "volume/gpu_scene.glsl"
layout(std430, binding = BINDING_points) readonly buffer Points {
  vec4 points[];
};
layout(std430, binding = BINDING_sigma) writeonly buffer Sigma {
  float sigma[];
};
layout(push_constant) uniform Push {
  uint count;
}
pc;
#include "volume/medium.glsl"

void main() {
  uint i = invocation_index();
  if (i >= pc.count) return;
  sigma[i] = sample_medium(points[i].xyz, 0.5f, 0.5f).sigma_t;
}
