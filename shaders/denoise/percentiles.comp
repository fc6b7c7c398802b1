#version 460
// SVGF pass 1: per 8x8 block, the luminance percentiles of the noisy input: firefly low/up over the 64
// pixels, adaptivity low/up over the 16 means of 2x2 quads (half the noise of single pixels, so outdated
// history stands out sooner; docs/denoising.md). One invocation per block sorts its 64 values and 16 quad
// means in registers with bitonic networks: no shared memory, no barrier, nothing that depends on the
// subgroup size, and 752 compare-exchanges per block where ranking every value against every other took
// 4352 comparisons. Pixels outside the image do not take part.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 8, local_size_y = 8) in;

#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_colour) readonly buffer Input {
  float colour[];
};
layout(std430, binding = BINDING_percentiles) writeonly buffer Percentiles {
  vec4 percentiles[];
};

#include "denoise/svgf_common.glsl"

// The block's 64 luminances (row-major), then its 16 quad means. Every index below is a constant once the
// functions are inlined and the loops unrolled, so the array lives in registers; a dynamic index would
// move it to memory.
float v[80];

// The noisy input's luminance at a pixel; non-finite input counts as 0 (as the accumulation sees it).
float input_luminance(uint p) {
  uint b = p * P.layout_in.x + P.layout_in.y;
  vec3 c = vec3(colour[b], colour[b + 1u], colour[b + 2u]);
  float y = luminance(c);
  return svgf_finite(vec4(c, y)) ? max(y, 0.0f) : 0.0f;
}

// One merge of a bitonic network over v[first, first + n): compare-exchange i with i ^ j for j = k/2, ...,
// 1, ascending where bit k of i is 0. Counted loops over constants only, so that they unroll.
void bitonic_merge(uint first, uint n, uint k) {
  [[unroll]] for (int t = 0; t < findMSB(k); ++t) {
    uint j = (k >> 1u) >> uint(t);
    [[unroll]] for (uint i = 0u; i < n; ++i) {
      uint l = i ^ j;
      if (l > i) {
        float a = v[first + i], b = v[first + l];
        bool ascending = (i & k) == 0u;
        v[first + i] = ascending ? min(a, b) : max(a, b);
        v[first + l] = ascending ? max(a, b) : min(a, b);
      }
    }
  }
}

// v[first, first + n) in ascending order, n = 16 or 64.
void bitonic_sort(uint first, uint n) {
  bitonic_merge(first, n, 2u);
  bitonic_merge(first, n, 4u);
  bitonic_merge(first, n, 8u);
  bitonic_merge(first, n, 16u);
  if (n >= 32u) bitonic_merge(first, n, 32u);
  if (n >= 64u) bitonic_merge(first, n, 64u);
}

// Quantile q of the n smallest of the sorted v[first, first + size), interpolated between ranks. The two
// ranks are selected, not indexed (see v).
float quantile(float q, uint first, uint size, uint n) {
  float x = clamp(q, 0.0f, 1.0f) * float(n - 1u);
  uint i = uint(x);
  uint j = min(i + 1u, n - 1u);
  float a = 0.0f, b = 0.0f;
  [[unroll]] for (uint k = 0u; k < size; ++k) {
    a = k == i ? v[first + k] : a;
    b = k == j ? v[first + k] : b;
  }
  return mix(a, b, x - float(i));
}

void main() {
  uvec2 block = gl_GlobalInvocationID.xy;
  if (any(greaterThanEqual(block, P.size.zw))) return;
  // The block's extent inside the image; pixels outside hold +inf, so they sort after every real value.
  uvec2 origin = block * 8u;
  uvec2 extent = min(uvec2(8u), P.size.xy - origin);
  const float INF = uintBitsToFloat(0x7f800000u);
  [[unroll]] for (uint k = 0u; k < 64u; ++k) {
    uvec2 local = uvec2(k % 8u, k / 8u);
    uvec2 pix = origin + local;
    v[k] = all(lessThan(local, extent)) ? input_luminance(pix.y * P.size.x + pix.x) : INF;
  }
  // Each 2x2 quad's mean over its pixels inside the image.
  [[unroll]] for (uint ql = 0u; ql < 16u; ++ql) {
    uvec2 corner = 2u * uvec2(ql % 4u, ql / 4u);
    float sum = 0.0f, m = 0.0f;
    [[unroll]] for (uint k = 0u; k < 4u; ++k) {
      uvec2 q = corner + uvec2(k & 1u, k >> 1u);
      if (all(lessThan(q, extent))) {
        sum += v[q.y * 8u + q.x];
        m += 1.0f;
      }
    }
    v[64u + ql] = m > 0.0f ? sum / m : INF;
  }
  bitonic_sort(0u, 64u);
  bitonic_sort(64u, 16u);
  uint n = extent.x * extent.y;
  uint nq = ((extent.x + 1u) / 2u) * ((extent.y + 1u) / 2u);
  percentiles[block.y * P.size.z + block.x] =
      vec4(quantile(P.percentiles.x, 0u, 64u, n), quantile(P.percentiles.y, 0u, 64u, n),
           quantile(P.percentiles.z, 64u, 16u, nq), quantile(P.percentiles.w, 64u, 16u, nq));
}
