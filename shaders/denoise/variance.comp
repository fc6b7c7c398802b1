#version 460
// SVGF pass 3: the variance estimate. Adaptive mode: luminance moments over a 5x5 neighbourhood with
// weights h(|dx|) h(|dy|), h = [1, 2/3, 1/6], times normal and depth terms, blended with the temporal
// moments by beta = clamp(b / n^f, 0, 1), optionally divided by the frames the colour averages (filter_sigma
// "estimate"). Classic mode (Schied et al. 2017): a 7x7 bilateral estimate
// while the history is shorter than 4 frames, else the temporal moments. Writes the filter's input
// (colour, sigma) and the moments and history length kept for the next frame.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
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

// The weight of neighbour q at offset (dx, dy) of the centre c in the spatial moments.
float moment_weight(GPixel c, GPixel q, int dx, int dy, float Yc, float Yq) {
  float w;
  if (CLASSIC != 0u) {
    // Falcor's moment filter: depth (phi 1), normal (exponent 128), luminance (phi 10).
    w = depth_weight(c, q, vec2(dx, dy), 1.0f) * pow(max(0.0f, dot(c.n, q.n)), 128.0f) *
        exp(-abs(Yc - Yq) / 10.0f);
  } else {
    const float h[3] = float[3](1.0f, 2.0f / 3.0f, 1.0f / 6.0f);
    w = h[abs(dx)] * h[abs(dy)];
    if (dot(c.n, q.n) < P.variance.x) w = 0.0f;
    w *= depth_weight(c, q, vec2(dx, dy), P.variance.y);
  }
  return w;
}

// One invocation estimates a column of SVGF_VARIANCE_ROWS pixels: each row of the union of their windows is
// loaded once and weighted for every pixel whose window holds it (12 rows of 5 for 8 pixels instead of 8
// windows of 25), in each pixel's own order (dy, then dx), so the sums are those of one window at a time.
const uint K = SVGF_VARIANCE_ROWS;

void main() {
  uint W = P.size.x, H = P.size.y;
  uint x = gl_GlobalInvocationID.x, y0 = gl_GlobalInvocationID.y * K;
  if (x >= W || y0 >= H) return;
  const int R = CLASSIC != 0u ? 3 : 2;
  GPixel c[K];
  vec4 cn[K];
  vec2 m[K], ms[K];
  float n[K], Yc[K], wsum[K];
  [[unroll]] for (uint k = 0u; k < K; ++k) {
    // Rows past the image repeat the last one and are not written.
    uint p = min(y0 + k, H - 1u) * W + x;
    c[k] = g_load(p);
    cn[k] = unpack_half4(acc_colour[p]);
    n[k] = max(cn[k].w, 1.0f);
    m[k] = moments_at(p);
    Yc[k] = luminance(cn[k].rgb);
    ms[k] = vec2(0.0f);
    wsum[k] = 0.0f;
  }
  [[unroll]] for (int r = -R; r < int(K) + R; ++r) {
    int qy = int(y0) + r;
    [[unroll]] for (int dx = -R; dx <= R; ++dx) {
      int qx = int(x) + dx;
      if (qy < 0 || qy >= int(H) || qx < 0 || qx >= int(W)) continue;
      uint qp = uint(qy) * W + uint(qx);
      GPixel q = g_load_tap(qp);
      vec2 mq = moments_at(qp);
      float Yq = CLASSIC != 0u ? luminance(unpack_half4(acc_colour[qp]).rgb) : 0.0f;
      [[unroll]] for (int k = 0; k < int(K); ++k) {
        int dy = r - k;
        if (abs(dy) > R) continue;
        float w = moment_weight(c[k], q, dx, dy, Yc[k], Yq);
        ms[k] += w * mq;
        wsum[k] += w;
      }
    }
  }
  [[unroll]] for (uint k = 0u; k < K; ++k) {
    if (y0 + k >= H) continue;
    uint p = (y0 + k) * W + x;
    uint hb = p * SVGF_MOMENTS_STRIDE;
    hist_moments[hb] = m[k].x;
    hist_moments[hb + 1u] = m[k].y;
    hist_moments[hb + 2u] = n[k];
    bool spatial = CLASSIC == 0u || n[k] < 4.0f;
    vec2 s = spatial ? ms[k] / max(wsum[k], 1e-12f) : vec2(0.0f);
    float var;
    if (CLASSIC != 0u) {
      var = spatial ? max(0.0f, s.y - s.x * s.x) * 4.0f / n[k] : max(0.0f, m[k].y - m[k].x * m[k].x);
    } else {
      float beta = clamp(P.variance.z / pow(n[k], P.variance.w), 0.0f, 1.0f);
      vec2 mb = mix(m[k], s, beta);
      var = max(0.0f, mb.y - mb.x * mb.x);
      // filter_sigma "estimate": the variance of the accumulated mean, not of one frame's sample: n frames
      // averaged while alpha = 1/n, then the exponential average's (2 - alpha) / alpha.
      if (P.variance_scale.x > 0.5f) var /= min(n[k], (2.0f - P.variance_scale.y) / P.variance_scale.y);
    }
    out_colour[p] = pack_half4(vec4(cn[k].rgb, sqrt(var)));
  }
}
