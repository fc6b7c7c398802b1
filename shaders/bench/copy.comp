#version 460
#extension GL_GOOGLE_include_directive : require
// The yardstick for pass timings: a plain copy of the same number of floats a pass reads.
layout(local_size_x = 64) in;
#include "common/dispatch.glsl"
layout(std430, binding = BINDING_src) readonly buffer Src {
  vec4 src[];
};
layout(std430, binding = BINDING_dst) writeonly buffer Dst {
  vec4 dst[];
};
layout(push_constant) uniform Push {
  uint count;
}
pc;
void main() {
  uint i = invocation_index();
  if (i < pc.count) dst[i] = src[i];
}
