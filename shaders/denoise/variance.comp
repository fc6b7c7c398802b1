#version 460
// SVGF pass 3: the variance estimate. Adaptive mode: luminance moments over a 5x5 neighbourhood with
// weights h(|dx|) h(|dy|), h = [1, 2/3, 1/6], times normal and depth terms, blended with the temporal
// moments by beta = clamp(b / n^f, 0, 1), optionally divided by the frames the colour averages (filter_sigma
// "estimate"). Classic mode (Schied et al. 2017): a 7x7 bilateral estimate
// while the history is shorter than 4 frames, else the temporal moments. Writes the filter's input
// (colour, sigma) and the moments and history length kept for the next frame.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 0) const uint CLASSIC = 0u;

#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_acc_colour) readonly buffer AccColour {
  uvec2 acc_colour[];  // rgb, history length
};
layout(std430, binding = BINDING_acc_moments) readonly buffer AccMoments {
  uvec2 acc_moments[];  // m1, m2 as float bits
};
layout(std430, binding = BINDING_out_colour) writeonly buffer OutColour {
  uvec2 out_colour[];  // rgb, sigma
};
layout(std430, binding = BINDING_hist_moments) writeonly buffer HistoryMoments {
  float hist_moments[];  // m1, m2, n for the next frame
};

#include "denoise/svgf_common.glsl"

vec2 moments_at(uint p) {
  return uintBitsToFloat(acc_moments[p]);
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  uint W = P.size.x, H = P.size.y;
  if (pix.x >= W || pix.y >= H) return;
  uint p = pix.y * W + pix.x;
  GPixel c = g_load(p);
  vec4 cn = unpack_half4(acc_colour[p]);
  float n = max(cn.w, 1.0f);
  vec2 m = moments_at(p);
  uint hb = p * SVGF_MOMENTS_STRIDE;
  hist_moments[hb] = m.x;
  hist_moments[hb + 1u] = m.y;
  hist_moments[hb + 2u] = n;

  const int R = CLASSIC != 0u ? 3 : 2;
  bool spatial = CLASSIC == 0u || n < 4.0f;
  vec2 ms = vec2(0.0f);
  float wsum = 0.0f;
  if (spatial) {
    float Yc = luminance(cn.rgb);
    for (int dy = -R; dy <= R; ++dy)
      for (int dx = -R; dx <= R; ++dx) {
        ivec2 qi = ivec2(pix) + ivec2(dx, dy);
        if (any(lessThan(qi, ivec2(0))) || any(greaterThanEqual(qi, ivec2(W, H)))) continue;
        uint qp = uint(qi.y) * W + uint(qi.x);
        GPixel q = g_load(qp);
        float w;
        if (CLASSIC != 0u) {
          // Falcor's moment filter: depth (phi 1), normal (exponent 128), luminance (phi 10).
          float Yq = luminance(unpack_half4(acc_colour[qp]).rgb);
          w = depth_weight(c, q, vec2(dx, dy), 1.0f) * pow(max(0.0f, dot(c.n, q.n)), 128.0f) *
              exp(-abs(Yc - Yq) / 10.0f);
        } else {
          const float h[3] = float[3](1.0f, 2.0f / 3.0f, 1.0f / 6.0f);
          w = h[abs(dx)] * h[abs(dy)];
          if (dot(c.n, q.n) < P.variance.x) w = 0.0f;
          w *= depth_weight(c, q, vec2(dx, dy), P.variance.y);
        }
        ms += w * moments_at(qp);
        wsum += w;
      }
    ms /= max(wsum, 1e-12f);
  }
  float var;
  if (CLASSIC != 0u) {
    var = spatial ? max(0.0f, ms.y - ms.x * ms.x) * 4.0f / n : max(0.0f, m.y - m.x * m.x);
  } else {
    float beta = clamp(P.variance.z / pow(n, P.variance.w), 0.0f, 1.0f);
    vec2 mb = mix(m, ms, beta);
    var = max(0.0f, mb.y - mb.x * mb.x);
    // filter_sigma "estimate": the variance of the accumulated mean, not of one frame's sample: n frames
    // averaged while alpha = 1/n, then the exponential average's (2 - alpha) / alpha.
    if (P.variance_scale.x > 0.5f) var /= min(n, (2.0f - P.variance_scale.y) / P.variance_scale.y);
  }
  out_colour[p] = pack_half4(vec4(cn.rgb, sqrt(var)));
}
