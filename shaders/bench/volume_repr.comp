#version 460
// PNanoVDB against a dense float array of the same grid, doing the same work: each invocation sums `n`
// trilinear density lookups at index-space points, either uniform random points of the domain (MARCH = 0)
// or `n` equally spaced points on the segment between two random points of the domain (MARCH = 1, a
// fixed-count ray march). Without HAZE_DENSE the lookups go through grid_trilinear() of
// volume/grids.glsl, the tracker's own code; with HAZE_DENSE through dense[], an x-fastest array of the
// box dense_origin .. dense_origin + dense_dims - 1 (indices outside it clamp to its border, which the host
// fills with the background 0). One lookup call site, in a loop (lavapipe: about 1 s of pipeline creation
// per inlined PNanoVDB lookup).
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 64) in;
#include "common/dispatch.glsl"
layout(constant_id = 0) const uint MARCH = 0u;
#define HAZE_HETERO 1
#include "common/color.glsl"
#include "common/compat.glsl"
#include "common/rng.glsl"
#include "common/sampling.glsl"
#include "volume/gpu_scene.glsl"
// medium.glsl reads scene, media[] and majorant[] in functions this kernel never calls: declared, not bound
// to anything the kernel uses (the host passes a small placeholder).
layout(std430, binding = BINDING_dense) readonly buffer DenseBuffer {
  float dense[];
};
layout(std430, binding = BINDING_result) writeonly buffer OutBuffer {
  float result[];
};
layout(push_constant) uniform Push {
  uint count;        // invocations
  uint n;            // lookups per invocation
  uint grid;         // the NanoVDB grid's index in the binding "grids"
  uint seed;
  vec4 lo;             // index-space domain of the points: lo.xyz .. hi.xyz
  vec4 hi;             //
  ivec4 dense_origin;  // index of dense[0]
  ivec4 dense_dims;    // extent of the dense box
}
pc;
#include "volume/medium.glsl"

#if HAZE_DENSE
HAZE_INLINE float dense_at(ivec3 ijk) {
  ivec3 d = clamp(ijk - pc.dense_origin.xyz, ivec3(0), pc.dense_dims.xyz - 1);
  return dense[(d.z * pc.dense_dims.y + d.y) * pc.dense_dims.x + d.x];
}

// Trilinear by hand, weights and summation order as in grid_trilinear().
float dense_trilinear(vec3 p) {
  vec3 pf = floor(p);
  ivec3 i0 = ivec3(pf);
  vec3 f = p - pf;
  float sum = 0.0f;
  [[unroll]] for (int c = 0; c < 8; ++c) {
    ivec3 o = ivec3(c & 1, (c >> 1) & 1, c >> 2);
    vec3 w3 = mix(vec3(1.0f) - f, f, vec3(o));
    sum += w3.x * w3.y * w3.z * dense_at(i0 + o);
  }
  return sum;
}
#endif

vec3 domain_point(INOUT(uint) rng) {
  vec3 u = vec3(rng_next(rng), rng_next(rng), rng_next(rng));
  return pc.lo.xyz + (pc.hi.xyz - pc.lo.xyz) * u;
}

void main() {
  uint i = invocation_index();
  if (i >= pc.count) return;
  uint rng = rng_init(pc.seed, i, 0u);
  vec3 a = vec3(0.0f), b = vec3(0.0f);
  if (MARCH != 0u) {
    a = domain_point(rng);
    b = domain_point(rng);
  }
  float sum = 0.0f;
  [[dont_unroll]] for (uint k = 0u; k < pc.n; ++k) {
    vec3 p = MARCH != 0u ? a + (b - a) * ((float(k) + 0.5f) / float(pc.n)) : domain_point(rng);
#if HAZE_DENSE
    sum += dense_trilinear(p);
#else
    sum += grid_trilinear(pc.grid, p);
#endif
  }
  result[i] = sum;
}
