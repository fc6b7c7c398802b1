#version 460
// SVGF pass 5: remodulation by albedo (plus the emission kept out of the demodulation) and temporal
// anti-aliasing. The previous output, fetched bilinearly at the reprojected position, is clamped to the
// current 3x3 neighbourhood (its min/max box, or mean +- gamma sigma) and blended:
// out = mix(current, clamped history, blend).
#extension GL_GOOGLE_include_directive : require
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

vec3 current(uint p) {
  vec3 albedo = remodulation(p);
  return unpack_half4(filtered[p]).rgb * albedo + emitted(p);
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  uint W = P.size.x, H = P.size.y;
  if (pix.x >= W || pix.y >= H) return;
  uint p = pix.y * W + pix.x;
  vec4 f = unpack_half4(filtered[p]);
  vec3 albedo = remodulation(p);
  vec3 cur = f.rgb * albedo + emitted(p);
  float sigma = f.w * luminance(albedo);
  vec3 result = cur;
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
    vec3 lo = cur, hi = cur, mean = vec3(0.0f), m2 = vec3(0.0f);
    float n = 0.0f;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx) {
        ivec2 qi = ivec2(pix) + ivec2(dx, dy);
        if (any(lessThan(qi, ivec2(0))) || any(greaterThanEqual(qi, ivec2(W, H)))) continue;
        vec3 c = current(uint(qi.y) * W + uint(qi.x));
        lo = min(lo, c);
        hi = max(hi, c);
        mean += c;
        m2 += c * c;
        n += 1.0f;
      }
    if (P.taa.y > 0.5f) {
      mean /= n;
      vec3 s = sqrt(max(m2 / n - mean * mean, vec3(0.0f)));
      lo = mean - P.taa.z * s;
      hi = mean + P.taa.z * s;
    }
    result = mix(cur, clamp(hist, lo, hi), P.taa.x);
  }
  outp[p] = pack_half4(vec4(result, sigma));
}
