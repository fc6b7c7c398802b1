#version 460
// SVGF pass 1: per 8x8 block, the luminance percentiles of the noisy input: firefly low/up over the 64
// pixels, adaptivity low/up over the 16 means of 2x2 quads (half the noise of single pixels, so outdated
// history stands out sooner; docs/denoising.md). Rank selection in shared memory: each lane counts the
// values below its own, so a block is sorted with one barrier; pixels outside the image do not take part.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8, local_size_y = 8) in;

#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_colour) readonly buffer Input {
  float colour[];
};
layout(std430, binding = BINDING_percentiles) writeonly buffer Percentiles {
  vec4 percentiles[];
};

#include "denoise/svgf_common.glsl"

shared float values[64];
shared float quad_values[16];
shared float sorted[80];  // the 64 pixels, then the 16 quad means

// The noisy input's luminance at a pixel; non-finite input counts as 0 (as the accumulation sees it).
float input_luminance(uint p) {
  uint b = p * P.layout_in.x + P.layout_in.y;
  vec3 c = vec3(colour[b], colour[b + 1u], colour[b + 2u]);
  float y = luminance(c);
  return svgf_finite(vec4(c, y)) ? max(y, 0.0f) : 0.0f;
}

// Quantile q of the n sorted values starting at sorted[first], interpolated between ranks.
float quantile(float q, uint first, uint n) {
  float x = clamp(q, 0.0f, 1.0f) * float(n - 1u);
  uint i = uint(x);
  uint j = min(i + 1u, n - 1u);
  return mix(sorted[first + i], sorted[first + j], x - float(i));
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  uvec2 local = gl_LocalInvocationID.xy;
  uint lane = gl_LocalInvocationIndex;
  // The block's extent inside the image; pixels outside hold +inf, so they sort after every real value.
  uvec2 extent = min(uvec2(8u), P.size.xy - gl_WorkGroupID.xy * 8u);
  const float INF = uintBitsToFloat(0x7f800000u);
  bool inside = all(lessThan(local, extent));
  values[lane] = inside ? input_luminance(pix.y * P.size.x + pix.x) : INF;
  barrier();
  // The quad of 2x2 pixels whose top-left lane this is: the mean of its pixels inside the image.
  uvec2 quad = local / 2u;
  uint ql = quad.y * 4u + quad.x;
  bool quad_lane = local.x % 2u == 0u && local.y % 2u == 0u;
  if (quad_lane) {
    float sum = 0.0f, m = 0.0f;
    for (uint k = 0u; k < 4u; ++k) {
      uvec2 q = local + uvec2(k & 1u, k >> 1u);
      if (all(lessThan(q, extent))) {
        sum += values[q.y * 8u + q.x];
        m += 1.0f;
      }
    }
    quad_values[ql] = m > 0.0f ? sum / m : INF;
  }
  barrier();
  // Rank selection (ties broken by lane).
  float v = values[lane];
  uint rank = 0u;
  for (uint k = 0u; k < 64u; ++k) {
    float w = values[k];
    rank += (w < v || (w == v && k < lane)) ? 1u : 0u;
  }
  sorted[rank] = v;
  if (quad_lane) {
    float u = quad_values[ql];
    uint qrank = 0u;
    for (uint k = 0u; k < 16u; ++k) {
      float w = quad_values[k];
      qrank += (w < u || (w == u && k < ql)) ? 1u : 0u;
    }
    sorted[64u + qrank] = u;
  }
  barrier();
  if (lane == 0u) {
    uint n = extent.x * extent.y;
    uint nq = ((extent.x + 1u) / 2u) * ((extent.y + 1u) / 2u);
    percentiles[gl_WorkGroupID.y * P.size.z + gl_WorkGroupID.x] =
        vec4(quantile(P.percentiles.x, 0u, n), quantile(P.percentiles.y, 0u, n),
             quantile(P.percentiles.z, 64u, nq), quantile(P.percentiles.w, 64u, nq));
  }
}
