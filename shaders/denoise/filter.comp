#version 460
// SVGF pass 4, one filter iteration at gap 2^i: edge-avoiding a-trous over (colour, sigma), variance
// propagated with squared weights. Adaptive mode: luminance term exp(-(|dY| / (phi_l sigma + eps))^2),
// depth and normal terms that fade towards 1 with the centre's distance (beta = smoothstep(0, zbias, z)),
// and either the full 5x5 kernel or the subsampled 6-tap one (axis taps at +-2 alternating x/y per
// iteration, plus the four diagonals). Classic mode (Schied et al. 2017): 5x5, exp(-|dY| / (phi_l
// sqrt(g3x3(var)) + eps) - |dz| / (phi_z |grad z . d| + eps)) max(0, n.n')^phi_n.
//
// Normalization (adaptive mode): gather divides each output by the sum of its own weights, as SVGF does;
// on skewed noise the luminance term then keeps dark centres from their bright neighbours more than the
// reverse and the filter loses energy. Splat (SVGF_SPLAT) uses symmetric weights and divides each input by
// the sum of the weights it gives away, W_q, computed first (specialization constant WEIGHT_SUM): out_p =
// sum_q w_pq x_q / W_q, so the sum over pixels of the output equals the input's exactly.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 0) const uint CLASSIC = 0u;
layout(constant_id = 1) const uint SUBSAMPLED = 0u;
layout(constant_id = 2) const uint WEIGHT_SUM = 0u;

#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_in_colour) readonly buffer In {
  uvec2 in_colour[];  // rgb, sigma
};
#ifdef SVGF_SPLAT
// Per pixel the sum of the symmetric weights it gives to its taps and itself (written by WEIGHT_SUM).
layout(std430, binding = BINDING_weight_sum) buffer WeightSum {
  float weight_sum[];
};
#endif
layout(std430, binding = BINDING_out_colour) writeonly buffer Out {
  uvec2 out_colour[];
};

layout(push_constant) uniform Push {
  uint iteration;
}
pc;

#include "denoise/svgf_common.glsl"

// B3-spline a-trous weights for offsets 0, 1, 2.
const float KERNEL[3] = float[3](3.0f / 8.0f, 1.0f / 4.0f, 1.0f / 16.0f);

bool inside(ivec2 q) {
  return all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, ivec2(P.size.xy)));
}

// Classic: the centre's variance blurred by a 3x3 Gaussian before it steers the luminance term.
float prefiltered_variance(ivec2 pix) {
  const float g[2] = float[2](1.0f / 4.0f, 1.0f / 8.0f);
  float v = 0.0f, wsum = 0.0f;
  for (int dy = -1; dy <= 1; ++dy)
    for (int dx = -1; dx <= 1; ++dx) {
      ivec2 q = pix + ivec2(dx, dy);
      if (!inside(q)) continue;
      float w = g[abs(dx)] * g[abs(dy)] * (dx == 0 && dy == 0 ? 2.0f : 1.0f);
      float s = unpack_half4(in_colour[uint(q.y) * P.size.x + uint(q.x)]).w;
      v += w * s * s;
      wsum += w;
    }
  return v / wsum;
}

// One invocation filters a strip of SVGF_FILTER_STRIP pixels along the kernel's axis (x for the 5x5 kernel,
// the iteration's axis for the subsampled one), spaced so that their taps overlap: each tap is loaded and
// decoded once for every pixel that uses it (16 loads for 4 pixels instead of 28 subsampled, 40 instead of
// 100 for 5x5), then weighted per pixel in that pixel's own order, so the sums are those of one pixel at a
// time.
const int K = int(SVGF_FILTER_STRIP);

struct FilterTap {
  vec4 c;  // rgb, sigma
  GPixel g;
  float Y;
  uint p;
  bool valid;  // inside the image
};

FilterTap filter_tap(ivec2 q) {
  FilterTap t;
  t.valid = inside(q);
  t.p = t.valid ? uint(q.y) * P.size.x + uint(q.x) : 0u;
  t.c = vec4(0.0f);
  t.g = GPixel(0.0f, vec2(0.0f), vec3(0.0f), vec3(0.0f), 0u, 0.0f);
  t.Y = 0.0f;
  if (t.valid) {
    t.c = unpack_half4(in_colour[t.p]);
    t.g = g_load_tap(t.p);
    t.Y = luminance(t.c.rgb);
  }
  return t;
}

struct FilterSums {
  vec3 c;
  float v, w;
};

// Adds tap t at offset o (pixels) with kernel weight k to the sums of centre c; rcp_z: c's depth scale for
// +-o.
void filter_add(INOUT(FilterSums) s, FilterCentre c, FilterTap t, vec2 o, float k, float rcp_z) {
  if (!t.valid) return;
  float w;
  if (CLASSIC != 0u) {
    w = k * exp(-(abs(t.Y - c.Y) * c.rcp_luminance + depth_exponent(c.g, t.g, rcp_z))) *
        pow(max(0.0f, dot(c.g.n, t.g.n)), P.filter_phi.z);
  } else {
#ifdef SVGF_SPLAT
    w = k * filter_weight_symmetric(c, filter_centre(t.g, t.Y, t.c.w), o);
    if (WEIGHT_SUM == 0u) w /= weight_sum[t.p];  // the share of q's signal that reaches this pixel
#else
    w = k * filter_weight(c, t.g, t.Y, rcp_z);
#endif
  }
  s.c += w * t.c.rgb;
  s.v += w * w * t.c.w * t.c.w;
  s.w += w;
}

// The centre tap has weight KERNEL[0]^2 and is identical to itself.
FilterSums filter_start(FilterTap t) {
  float k0 = KERNEL[0] * KERNEL[0];
#ifdef SVGF_SPLAT
  if (WEIGHT_SUM == 0u) k0 /= weight_sum[t.p];
#endif
  FilterSums s;
  s.c = k0 * t.c.rgb;
  s.v = k0 * k0 * t.c.w * t.c.w;
  s.w = k0;
  return s;
}

FilterCentre filter_centre_at(FilterTap t, ivec2 pix) {
  float sigma = CLASSIC != 0u ? sqrt(prefiltered_variance(pix)) : t.c.w;
  return filter_centre(g_load(t.p), t.Y, sigma);
}

void filter_store(FilterSums s, uint p) {
#ifdef SVGF_SPLAT
  if (WEIGHT_SUM != 0u) {
    weight_sum[p] = s.w;
    return;
  }
  // The shares already carry their normalization.
  out_colour[p] = pack_half4(vec4(s.c, sqrt(s.v)));
#else
  out_colour[p] = pack_half4(vec4(s.c / s.w, sqrt(s.v) / s.w));
#endif
}

void main() {
  const int gap = 1 << pc.iteration;
  // The strip: pixels base + j s du, j < K; invocation a along du covers residue a mod s of block a / s.
  const bool x_axis = SUBSAMPLED == 0u || (pc.iteration & 1u) == 0u;
  const int s = SUBSAMPLED != 0u ? 2 * gap : gap;
  ivec2 du = x_axis ? ivec2(1, 0) : ivec2(0, 1), dv = du.yx;
  ivec2 gid = ivec2(gl_GlobalInvocationID.xy);
  int a = x_axis ? gid.x : gid.y;
  ivec2 base = (a / s) * s * K * du + (a % s) * du + (x_axis ? gid.y : gid.x) * dv;
  if (!inside(base)) return;  // so is the rest of the strip

  FilterCentre centre[K];
  FilterSums sums[K];
  if (SUBSAMPLED != 0u) {
    // A: the strip's row, its pixels and one more at each end (the axis taps at +-2 gaps); D+, D-: the
    // diagonal taps at +-1 gap across it, between the pixels.
    FilterTap A[K + 2], Dp[K + 1], Dm[K + 1];
    [[unroll]] for (int m = 0; m < K + 2; ++m) A[m] = filter_tap(base + (m - 1) * s * du);
    [[unroll]] for (int m = 0; m <= K; ++m) {
      ivec2 q = base + (m * s - gap) * du;
      Dp[m] = filter_tap(q + gap * dv);
      Dm[m] = filter_tap(q - gap * dv);
    }
    vec2 axis = vec2(2 * gap * du), diag = vec2(gap), anti = vec2(-gap, gap);
    float ka = KERNEL[2] * KERNEL[0], kd = KERNEL[1] * KERNEL[1];
    [[unroll]] for (int j = 0; j < K; ++j) {
      if (!A[j + 1].valid) continue;
      FilterCentre c = filter_centre_at(A[j + 1], base + j * s * du);
      FilterSums sj = filter_start(A[j + 1]);
      float rcp_a = filter_depth_rcp(c, axis);
      filter_add(sj, c, A[j + 2], axis, ka, rcp_a);
      filter_add(sj, c, A[j], -axis, ka, rcp_a);
      // The diagonals (1, 1), (-1, 1), (1, -1), (-1, -1) in pixels; each depth scale is shared by a tap and
      // its mirror.
      float rcp_d = filter_depth_rcp(c, diag), rcp_e = filter_depth_rcp(c, anti);
      filter_add(sj, c, Dp[j + 1], diag, kd, rcp_d);
      filter_add(sj, c, x_axis ? Dp[j] : Dm[j + 1], anti, kd, rcp_e);
      filter_add(sj, c, x_axis ? Dm[j + 1] : Dp[j], -anti, kd, rcp_e);
      filter_add(sj, c, Dm[j], -diag, kd, rcp_d);
      filter_store(sj, A[j + 1].p);
    }
  } else {
    // 5x5 along x (s = gap): row dy of all K windows is K + 4 taps.
    bool live[K];
    uint pj[K];
    [[unroll]] for (int j = 0; j < K; ++j) {
      FilterTap t = filter_tap(base + ivec2(j * gap, 0));
      live[j] = t.valid;
      pj[j] = t.p;
      if (!t.valid) continue;
      centre[j] = filter_centre_at(t, base + ivec2(j * gap, 0));
      sums[j] = filter_start(t);
    }
    [[dont_unroll]] for (int dy = -2; dy <= 2; ++dy) {
      FilterTap R[K + 4];
      [[unroll]] for (int m = 0; m < K + 4; ++m) R[m] = filter_tap(base + ivec2(m - 2, dy) * gap);
      [[unroll]] for (int j = 0; j < K; ++j) {
        if (!live[j]) continue;
        [[unroll]] for (int dx = -2; dx <= 2; ++dx) {
          if (dx == 0 && dy == 0) continue;
          vec2 o = vec2(dx, dy) * float(gap);
          filter_add(sums[j], centre[j], R[j + dx + 2], o, KERNEL[abs(dx)] * KERNEL[abs(dy)],
                     filter_depth_rcp(centre[j], o));
        }
      }
    }
    [[unroll]] for (int j = 0; j < K; ++j) if (live[j]) filter_store(sums[j], pj[j]);
  }
}
