#version 460
// SVGF pass 2: temporal accumulation. Firefly clamp of the input (adaptive mode), reprojection of the
// history with normal and depth tests, stochastic bilinear taps, an extended search after rejection and
// border reuse for motion that leaves the screen (adaptive mode), the percentile-adaptive history cap, the
// history test against the neighbours' mean (adaptive mode, history_test > 0; on the previous frame's output
// with SVGF_HISTORY_WITNESS), and the blend of colour and luminance moments. The classic mode (Schied et al.
// 2017) averages the valid bilinear taps, falls back to a 3x3 search and blends with alpha = max(0.2, 1/n).
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 0) const uint CLASSIC = 0u;

#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_colour) readonly buffer Input {
  float colour[];
};
layout(std430, binding = BINDING_motion) readonly buffer Motion {
  float motion[];
};
layout(std430, binding = BINDING_percentiles) readonly buffer Percentiles {
  vec4 percentiles[];
};
layout(std430, binding = BINDING_hist_colour) readonly buffer HistoryColour {
  uvec2 hist_colour[];
};
layout(std430, binding = BINDING_hist_moments) readonly buffer HistoryMoments {
  float hist_moments[];
};
#ifdef SVGF_HISTORY_WITNESS
// The previous frame's denoised output (TAA's), what the history test judges (history_witness "output").
layout(std430, binding = BINDING_prev_output) readonly buffer PrevOutput {
  uvec2 prev_output[];
};
#ifdef SVGF_EPIPOLAR
// Pixels each way along the epipolar line that the witness averages, 9 in all (with 5 the volume's mean on
// the shaft sequence was -2.0% instead of -1.6%: a shorter line carries more of the pixel's own noise).
const int SVGF_WITNESS_REACH = 4;
#endif
#endif
layout(std430, binding = BINDING_out_colour) writeonly buffer OutColour {
  uvec2 out_colour[];  // rgb, history length
};
layout(std430, binding = BINDING_out_moments) writeonly buffer OutMoments {
  uvec2 out_moments[];  // m1, m2 as float bits
};

layout(push_constant) uniform Push {
  uint frame;
  uint has_history;
}
pc;

#include "common/rng.glsl"
#define SVGF_GEO_ACCESS    // own geometry: the accumulated virtual point depth is written back into geo
#define SVGF_GPACK_ACCESS  // G-buffer geometry: this pass packs the taps' words for the spatial passes
#include "denoise/svgf_common.glsl"

// Block percentiles, bilinear between block centres.
vec4 percentiles_at(uvec2 pix) {
  vec2 u = (vec2(pix) + 0.5f) / 8.0f - 0.5f;
  vec2 m = vec2(P.size.zw) - 1.0f;
  u = clamp(u, vec2(0.0f), m);
  uvec2 i = uvec2(floor(u));
  uvec2 j = min(i + 1u, uvec2(m));
  vec2 f = u - vec2(i);
  uint W = P.size.z;
  vec4 a = mix(percentiles[i.y * W + i.x], percentiles[i.y * W + j.x], f.x);
  vec4 b = mix(percentiles[j.y * W + i.x], percentiles[j.y * W + j.x], f.x);
  return mix(a, b, f.y);
}

// Whether the previous frame's pixel q shows the same surface as the current pixel c.
bool reprojection_valid(GPixel c, GPixel q) {
  if (c.z <= 0.0f || q.z <= 0.0f) return c.z <= 0.0f && q.z <= 0.0f;  // sky reprojects to sky
  if (CLASSIC != 0u) {
    // Falcor's SVGF: depth against the depth gradient, normals, mesh ids.
    if (abs(c.z - q.z) / (abs(c.dz.x) + abs(c.dz.y) + 1e-2f) > 10.0f) return false;
    if (distance(c.n, q.n) / 1e-2f > 16.0f) return false;
    return c.id == q.id;
  }
  float z_expected = c.z_prev > 0.0f ? c.z_prev : c.z;
  return dot(c.n, q.n) >= P.reproject.x && abs(z_expected - q.z) <= P.reproject.y * max(c.z, q.z);
}

// Soft version for the extended search: 1 for a perfect match, 0 past the thresholds.
float reprojection_weight(GPixel c, GPixel q) {
  if (!reprojection_valid(c, q)) return 0.0f;
  if (c.z <= 0.0f) return 1.0f;
  float z_expected = c.z_prev > 0.0f ? c.z_prev : c.z;
  float wz = 1.0f - abs(z_expected - q.z) / (P.reproject.y * max(c.z, q.z) + 1e-12f);
  float wn = linstep(P.reproject.x, 1.0f, dot(c.n, q.n));
  return max(wz * (P.reproject.x < 1.0f ? wn : 1.0f), 1e-6f);
}

struct History {
  vec3 colour;
  float m1, m2, n;
  float m1_z;  // own geometry: m1 times the history's virtual point depth
#ifdef SVGF_HISTORY_WITNESS
  float Y_w;  // the history test's witness: the luminance of the previous output there
#endif
};

History history_at(uint p, float weight) {
  History h;
  vec4 c = unpack_half4(hist_colour[p]);
  uint b = p * SVGF_MOMENTS_STRIDE;
  h.colour = c.rgb * weight;
  h.m1 = hist_moments[b] * weight;
  h.m2 = hist_moments[b + 1u] * weight;
  h.n = hist_moments[b + 2u] * weight;
#ifdef SVGF_HISTORY_WITNESS
  h.Y_w = luminance(unpack_half4(prev_output[p]).rgb) * weight;
#endif
#ifdef SVGF_OWN_GEOMETRY
  h.m1_z = h.m1 * prev_geo[p];
#else
  h.m1_z = 0.0f;
#endif
  return h;
}

void add(INOUT(History) a, History b) {
  a.colour += b.colour;
  a.m1 += b.m1;
  a.m2 += b.m2;
  a.n += b.n;
  a.m1_z += b.m1_z;
#ifdef SVGF_HISTORY_WITNESS
  a.Y_w += b.Y_w;
#endif
}

bool inside(ivec2 q) {
  return all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, ivec2(P.size.xy)));
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  uint W = P.size.x, H = P.size.y;
  if (pix.x >= W || pix.y >= H) return;
  uint p = pix.y * W + pix.x;
  uint rng = rng_init(0x5f3759dfu, p, pc.frame);

  GPixel c = g_load(p);
#ifdef BINDING_gpack
  gpack[p] = g_pack(g_depth[p], g_normal[p]);
#endif
  uint ib = p * P.layout_in.x + P.layout_in.y;
  vec3 col = vec3(colour[ib], colour[ib + 1u], colour[ib + 2u]);
  if (!svgf_finite(vec4(col, 0.0f))) col = vec3(0.0f);
  // Storage is half float: the input saturates where the history would.
  col = clamp(col, vec3(0.0f), vec3(SVGF_HALF_MAX));
  float Y = luminance(col);
  vec4 pct = vec4(0.0f);
  float Y_max = SVGF_HALF_MAX;
  if (CLASSIC == 0u) {
    pct = percentiles_at(pix);
    // Firefly clamp: Y_max = min(hard clamp, bias + P_fu + k_f (P_fu - P_fl)).
    Y_max = min(P.firefly.z, P.firefly.x + pct.y + P.firefly.y * (pct.y - pct.x));
    if (Y > Y_max) {
      col *= Y_max / Y;
      Y = Y_max;
    }
  }
  float m1 = Y, m2 = Y * Y;

  // Previous pixel-centre position of this pixel's point.
  uint mb = p * P.layout_in.z + P.layout_in.w;
  vec2 mv = vec2(motion[mb], motion[mb + 1u]);
  if (!svgf_finite(vec4(mv, 0.0f, 0.0f))) mv = vec2(0.0f);
  vec2 q = vec2(pix) + 0.5f + mv;
  float cap = P.accumulate.y;
  bool found = false;
  History h;
  h.colour = vec3(0.0f);
  h.m1 = h.m2 = h.n = h.m1_z = 0.0f;
#ifdef SVGF_HISTORY_WITNESS
  h.Y_w = 0.0f;
#endif
  if (pc.has_history != 0u) {
    vec2 size = vec2(W, H);
    if (CLASSIC == 0u && (any(lessThan(q, vec2(0.0f))) || any(greaterThanEqual(q, size)))) {
      // Motion leaving the screen: walk back along it to the border and reuse the history there.
      vec2 o = vec2(pix) + 0.5f, d = q - o;
      d = mix(d, mix(vec2(-1e-12f), vec2(1e-12f), greaterThanEqual(d, vec2(0.0f))),
              lessThan(abs(d), vec2(1e-12f)));
      vec2 lo = (vec2(0.5f) - o) / d, hi = (size - 0.5f - o) / d;
      vec2 t_exit = max(lo, hi);  // per axis, where the segment leaves the [0.5, size - 0.5] box
      float t = clamp(min(t_exit.x, t_exit.y), 0.0f, 1.0f);
      q = o + d * t;
      cap = min(cap, P.reproject.z);
    }
    vec2 f = q - 0.5f;
    ivec2 i0 = ivec2(floor(f));
    vec2 fr = f - vec2(i0);
    float w[4] =
        float[4]((1.0f - fr.x) * (1.0f - fr.y), fr.x * (1.0f - fr.y), (1.0f - fr.x) * fr.y, fr.x * fr.y);
    float w_valid[4];
    float total = 0.0f;
    for (int t = 0; t < 4; ++t) {
      ivec2 qi = i0 + ivec2(t & 1, t >> 1);
      w_valid[t] = 0.0f;
      if (!inside(qi) || w[t] <= 0.0f) continue;
      if (reprojection_valid(c, g_load_prev(uint(qi.y) * W + uint(qi.x)))) w_valid[t] = w[t];
      total += w_valid[t];
    }
    if (total > 0.0f) {
      found = true;
      if (CLASSIC != 0u) {
        for (int t = 0; t < 4; ++t) {
          ivec2 qi = i0 + ivec2(t & 1, t >> 1);
          if (w_valid[t] > 0.0f) add(h, history_at(uint(qi.y) * W + uint(qi.x), w_valid[t] / total));
        }
      } else {
        // One tap, chosen with probability proportional to its bilinear weight: no blur accumulates.
        float u = rng_next(rng) * total;
        int pick = 3;
        for (int t = 0; t < 3; ++t) {
          if (u < w_valid[t]) {
            pick = t;
            break;
          }
          u -= w_valid[t];
        }
        while (w_valid[pick] <= 0.0f) pick -= 1;  // u landed past the last valid tap by rounding
        ivec2 qi = i0 + ivec2(pick & 1, pick >> 1);
        h = history_at(uint(qi.y) * W + uint(qi.x), 1.0f);
      }
    } else if (CLASSIC != 0u) {
      // Falcor's fallback: the valid pixels of the 3x3 around the reprojected position.
      float n_valid = 0.0f;
      ivec2 centre = ivec2(floor(q));
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          ivec2 qi = centre + ivec2(dx, dy);
          if (!inside(qi)) continue;
          uint qp = uint(qi.y) * W + uint(qi.x);
          if (!reprojection_valid(c, g_load_prev(qp))) continue;
          add(h, history_at(qp, 1.0f));
          n_valid += 1.0f;
        }
      if (n_valid > 0.0f) {
        found = true;
        h.colour /= n_valid;
        h.m1 /= n_valid;
        h.m2 /= n_valid;
        h.n /= n_valid;
        h.m1_z /= n_valid;
      }
    } else {
      // Extended search: random offsets in a 5x5 window, the best soft match wins.
      float best = 0.0f;
      uint best_p = 0u;
      for (int k = 0; k < 10; ++k) {
        ivec2 qi = ivec2(floor(q)) + ivec2(int(rng_next(rng) * 5.0f) - 2, int(rng_next(rng) * 5.0f) - 2);
        if (!inside(qi)) continue;
        uint qp = uint(qi.y) * W + uint(qi.x);
        float wq = reprojection_weight(c, g_load_prev(qp));
        if (wq > best) {
          best = wq;
          best_p = qp;
        }
      }
      if (best > 0.0f) {
        found = true;
        h = history_at(best_p, 1.0f);
      }
    }
  }

  float n = 1.0f, alpha = 1.0f;
#ifdef SVGF_OWN_GEOMETRY
  float m1_z = m1 * c.z;  // this frame's luminance times its (median-filtered) virtual point depth
#endif
  if (found) {
    if (CLASSIC == 0u) {
      // Percentile-adaptive cap: history far outside the block's adaptivity range is outdated.
      float Y_h = luminance(h.colour);
      float r = P.accumulate.w * (pct.w - pct.z);
      float s = P.accumulate.z;
      float m =
          (1.0f - s * linstep(pct.w, pct.w + r, Y_h)) * (1.0f - s * (1.0f - linstep(pct.z - r, pct.z, Y_h)));
      if (m < 1.0f) cap = min(cap, 1.0f / (1.0f - m));
      if (P.reproject.w > 0.0f) {
        // History test: this frame's mean of the (clamped) input luminance over the 8 neighbours and their
        // variance per sample, which also gives the history's (the same signal averaged over h.n frames). A
        // failed history gives way to this frame's sample. The pixel's own sample takes no part in the
        // decision, so the reset does not select on the value it keeps (with skewed noise that would bias the
        // mean). The history's own luminance is judged by default; with SVGF_HISTORY_WITNESS the previous
        // frame's denoised output at the same place, smooth, so that a bright history of skewed noise is not
        // cut for its own noise (which loses energy).
        float s1 = 0.0f, s2 = 0.0f, k = 0.0f;
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            ivec2 qi = ivec2(pix) + ivec2(dx, dy);
            if (!inside(qi) || (dx == 0 && dy == 0)) continue;
            uint qb = (uint(qi.y) * W + uint(qi.x)) * P.layout_in.x + P.layout_in.y;
            vec3 cq = max(vec3(colour[qb], colour[qb + 1u], colour[qb + 2u]), vec3(0.0f));
            float Yq = svgf_finite(vec4(cq, 0.0f)) ? min(luminance(cq), Y_max) : 0.0f;
            s1 += Yq;
            s2 += Yq * Yq;
            k += 1.0f;
          }
        float mean_n = s1 / k, var_q = max(s2 / k - mean_n * mean_n, 0.0f) * k / max(k - 1.0f, 1.0f);
        // Sparse noise leaves many neighbourhoods all zero (no variance seen): the history's own sample
        // variance bounds the estimate from below.
        var_q = max(var_q, h.m2 - h.m1 * h.m1);
#if defined(SVGF_HISTORY_WITNESS) && defined(SVGF_EPIPOLAR)
        // With the filter's epipolar term the output is smoothed less, and a witness of one pixel would carry
        // that pixel's own noise again: the witness is the mean over the epipolar line through it (this
        // frame's line at the reprojected position), smooth along the shafts and still sharp across them.
        float Y_judged = h.Y_w, n_w = 1.0f;
        vec2 along = epipolar_along(q);
        for (int i = -SVGF_WITNESS_REACH; i <= SVGF_WITNESS_REACH; ++i) {
          ivec2 wi = ivec2(floor(q + float(i) * along));
          if (i == 0 || !inside(wi)) continue;
          Y_judged += luminance(unpack_half4(prev_output[uint(wi.y) * W + uint(wi.x)]).rgb);
          n_w += 1.0f;
        }
        Y_judged /= n_w;
#elif defined(SVGF_HISTORY_WITNESS)
        const float Y_judged = h.Y_w;
#else
        const float Y_judged = Y_h;
#endif
        cap = mix(cap, 1.0f, history_test(Y_judged, var_q / max(h.n, 1.0f), mean_n, var_q / k));
      }
    }
    n = min(h.n + 1.0f, max(cap, 1.0f));
    alpha = max(1.0f - P.accumulate.x, 1.0f / n);
    col = mix(h.colour, col, alpha);
    m1 = mix(h.m1, m1, alpha);
    m2 = mix(h.m2, m2, alpha);
#ifdef SVGF_OWN_GEOMETRY
    m1_z = mix(h.m1_z, m1_z, alpha);
#endif
  }
#ifdef SVGF_OWN_GEOMETRY
  // The virtual point depth accumulates with the signal: the luminance-weighted mean of the history's depths,
  // what the gradient, the filter and the next frame's reprojection (and forward projection) then use. Frames
  // without a contribution weigh nothing; a pixel that never had one keeps this frame's depth.
  if (m1 > 0.0f && m1_z > 0.0f) geo[p].x = floatBitsToUint(m1_z / m1);
#endif
  out_colour[p] = pack_half4(vec4(col, n));
  out_moments[p] = uvec2(floatBitsToUint(m1), floatBitsToUint(m2));
}
