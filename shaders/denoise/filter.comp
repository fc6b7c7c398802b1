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
//
// SVGF_EPIPOLAR (adaptive mode): each tap's weight also falls with its distance from the centre's epipolar
// line (svgf_common.glsl), so the filter smooths along light shafts and not across them.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 0) const uint CLASSIC = 0u;
layout(constant_id = 1) const uint SUBSAMPLED = 0u;
layout(constant_id = 2) const uint WEIGHT_SUM = 0u;
layout(constant_id = 3) const uint PAIR_SIGMA = 0u;  // luminance_sigma "pair" (svgf_common.glsl)

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

vec3 sum_c;
float sum_v, sum_w;
FilterCentre centre;

void tap(ivec2 pix, ivec2 o, float k) {
  int gap = 1 << pc.iteration;
  ivec2 qi = pix + o * gap;
  if (!inside(qi)) return;
  uint qp = uint(qi.y) * P.size.x + uint(qi.x);
  vec4 cq = unpack_half4(in_colour[qp]);
  GPixel q = g_load_tap(qp);
  float Yq = luminance(cq.rgb);
  vec2 offset = vec2(o * gap);
  float w;
  if (CLASSIC != 0u) {
    w = k * exp(-abs(Yq - centre.Y) / centre.luminance_scale) *
        depth_weight(centre.g, q, offset, P.filter_phi.y) *
        pow(max(0.0f, dot(centre.g.n, q.n)), P.filter_phi.z);
  } else {
#ifdef SVGF_SPLAT
    w = k * filter_weight_symmetric(centre, filter_centre(q, Yq, cq.w, vec2(qi) + 0.5f), offset,
                                    PAIR_SIGMA != 0u);
    if (WEIGHT_SUM == 0u) w /= weight_sum[qp];  // the share of q's signal that reaches this pixel
#else
    float scale = PAIR_SIGMA != 0u ? pair_luminance_scale(centre.sigma, cq.w) : centre.luminance_scale;
    w = k * filter_weight(centre, q, Yq, scale, offset);
#endif
  }
  sum_c += w * cq.rgb;
  sum_v += w * w * cq.w * cq.w;
  sum_w += w;
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  if (pix.x >= P.size.x || pix.y >= P.size.y) return;
  uint p = pix.y * P.size.x + pix.x;
  vec4 c = unpack_half4(in_colour[p]);
  float sigma = CLASSIC != 0u ? sqrt(prefiltered_variance(ivec2(pix))) : c.w;
  centre = filter_centre(g_load(p), luminance(c.rgb), sigma, vec2(pix) + 0.5f);

  // The centre tap has weight KERNEL[0]^2 and is identical to itself.
  float k0 = KERNEL[0] * KERNEL[0];
#ifdef SVGF_SPLAT
  if (WEIGHT_SUM == 0u) k0 /= weight_sum[p];
#endif
  sum_c = k0 * c.rgb;
  sum_v = k0 * k0 * c.w * c.w;
  sum_w = k0;
  if (SUBSAMPLED != 0u) {
    ivec2 axis = (pc.iteration & 1u) == 0u ? ivec2(2, 0) : ivec2(0, 2);
    float ka = KERNEL[2] * KERNEL[0];
    tap(ivec2(pix), axis, ka);
    tap(ivec2(pix), -axis, ka);
    float kd = KERNEL[1] * KERNEL[1];
    tap(ivec2(pix), ivec2(1, 1), kd);
    tap(ivec2(pix), ivec2(-1, 1), kd);
    tap(ivec2(pix), ivec2(1, -1), kd);
    tap(ivec2(pix), ivec2(-1, -1), kd);
  } else {
    for (int dy = -2; dy <= 2; ++dy)
      for (int dx = -2; dx <= 2; ++dx)
        if (dx != 0 || dy != 0) tap(ivec2(pix), ivec2(dx, dy), KERNEL[abs(dx)] * KERNEL[abs(dy)]);
  }
#ifdef SVGF_SPLAT
  if (WEIGHT_SUM != 0u) {
    weight_sum[p] = sum_w;
    return;
  }
  // The shares already carry their normalization.
  out_colour[p] = pack_half4(vec4(sum_c, sqrt(sum_v)));
#else
  out_colour[p] = pack_half4(vec4(sum_c / sum_w, sqrt(sum_v) / sum_w));
#endif
}
