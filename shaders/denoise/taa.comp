#version 460
// SVGF pass 5: remodulation by albedo (plus the emission kept out of the demodulation) and temporal
// anti-aliasing. The previous output, fetched bilinearly at the reprojected position, is clamped to the
// current 3x3 neighbourhood (its min/max box, or mean +- gamma sigma) and blended:
// out = mix(current, clamped history, blend).
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 8, local_size_y = 8) in;

#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_motion) readonly buffer Motion {
  float motion[];
};
#ifdef SVGF_EMISSION
// The emission kept out of the demodulated input (scenes with emissive surfaces), added back unfiltered.
layout(std430, binding = BINDING_emission) readonly buffer Emission {
  float emission[];
};
#endif
layout(std430, binding = BINDING_filtered) readonly buffer Filtered {
  uvec2 filtered[];  // demodulated rgb, sigma
};
layout(std430, binding = BINDING_prev_output) readonly buffer PrevOutput {
  uvec2 prev_output[];
};
layout(std430, binding = BINDING_outp) writeonly buffer Output {
  uvec2 outp[];  // remodulated rgb, sigma of the filtered signal (remodulated by luminance)
};

layout(push_constant) uniform Push {
  uint has_history;
}
pc;

#include "denoise/svgf_common.glsl"

vec3 remodulation(uint p) {
  return P.flags.x != 0u ? demod_albedo(g_load(p)) : vec3(1.0f);
}

vec3 emitted(uint p) {
#ifdef SVGF_EMISSION
  uint i = p * P.flags.y + P.flags.z;
  return vec3(emission[i], emission[i + 1u], emission[i + 2u]);
#else
  return vec3(0.0f);
#endif
}

// One invocation blends a column of SVGF_TAA_ROWS pixels: the remodulated current signal of the 3 columns of
// their 3x3 boxes is computed once per pixel (3 (K + 2) instead of 9 K), each box then taken in its own
// order.
const int K = int(SVGF_TAA_ROWS);

void main() {
  uint W = P.size.x, H = P.size.y;
  int x = int(gl_GlobalInvocationID.x), y0 = int(gl_GlobalInvocationID.y) * K;
  if (x >= int(W) || y0 >= int(H)) return;
  // Rows y0 - 1 .. y0 + K, columns x - 1 .. x + 1; outside the image: not part of any box.
  vec3 cur[K + 2][3];
  bool valid[K + 2][3];
  vec4 f[K];
  vec3 albedo[K];
  [[unroll]] for (int r = 0; r < K + 2; ++r) [[unroll]] for (int i = 0; i < 3; ++i) {
    ivec2 qi = ivec2(x + i - 1, y0 + r - 1);
    valid[r][i] = all(greaterThanEqual(qi, ivec2(0))) && all(lessThan(qi, ivec2(W, H)));
    cur[r][i] = vec3(0.0f);
    if (!valid[r][i]) continue;
    uint q = uint(qi.y) * W + uint(qi.x);
    vec4 fq = unpack_half4(filtered[q]);
    vec3 aq = remodulation(q);
    cur[r][i] = fq.rgb * aq + emitted(q);
    if (i == 1 && r >= 1 && r <= K) {
      f[r - 1] = fq;
      albedo[r - 1] = aq;
    }
  }
  [[unroll]] for (int k = 0; k < K; ++k) {
    if (y0 + k >= int(H)) continue;
    uvec2 pix = uvec2(x, y0 + k);
    uint p = pix.y * W + pix.x;
    vec3 c = cur[k + 1][1];
    float sigma = f[k].w * luminance(albedo[k]);
    vec3 result = c;
    uint mb = p * P.layout_in.z + P.layout_in.w;
    vec2 q = vec2(pix) + 0.5f + vec2(motion[mb], motion[mb + 1u]);
    if (pc.has_history != 0u && svgf_finite(vec4(q, 0.0f, 0.0f)) && all(greaterThanEqual(q, vec2(0.0f))) &&
        all(lessThan(q, vec2(W, H)))) {
      // Bilinear history with clamped taps.
      vec2 g = q - 0.5f;
      ivec2 i0 = ivec2(floor(g));
      vec2 fr = g - vec2(i0);
      vec3 hist = vec3(0.0f);
      for (int t = 0; t < 4; ++t) {
        ivec2 qi = clamp(i0 + ivec2(t & 1, t >> 1), ivec2(0), ivec2(W - 1u, H - 1u));
        float w = ((t & 1) != 0 ? fr.x : 1.0f - fr.x) * ((t >> 1) != 0 ? fr.y : 1.0f - fr.y);
        hist += w * unpack_half4(prev_output[uint(qi.y) * W + uint(qi.x)]).rgb;
      }
      vec3 lo = c, hi = c, mean = vec3(0.0f), m2 = vec3(0.0f);
      float n = 0.0f;
      [[unroll]] for (int dy = -1; dy <= 1; ++dy) [[unroll]] for (int dx = -1; dx <= 1; ++dx) {
        if (!valid[k + 1 + dy][1 + dx]) continue;
        vec3 cq = cur[k + 1 + dy][1 + dx];
        lo = min(lo, cq);
        hi = max(hi, cq);
        mean += cq;
        m2 += cq * cq;
        n += 1.0f;
      }
      if (P.taa.y > 0.5f) {
        mean /= n;
        vec3 s = sqrt(max(m2 / n - mean * mean, vec3(0.0f)));
        lo = mean - P.taa.z * s;
        hi = mean + P.taa.z * s;
      }
      result = mix(c, clamp(hist, lo, hi), P.taa.x);
    }
    outp[p] = pack_half4(vec4(result, sigma));
  }
}
