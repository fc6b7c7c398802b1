#version 460
// The geometry of an SVGF instance with its own (geometry: virtual_points): the depth that its reprojection
// tests and edge-stopping terms compare, from the signal's virtual point depth. Two steps (specialization
// constant STEP):
//  0, before accumulation: keeps this pixel's depth of the last frame (prev_geo) and writes the median of the
//     valid depths of the 3x3 neighbourhood: a virtual point is the contribution-weighted mean of a few noisy
//     distances, and a median removes the isolated outliers without moving the steps between sheets.
//     Accumulation then replaces it with the depth accumulated over the history (accumulate.comp);
//  1, after accumulation: the screen-space gradient of that depth, per axis the one-sided difference of
//     smaller magnitude (at a step it stays on this pixel's side, as the G-buffer's does on the hit plane).
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8, local_size_y = 8) in;
layout(constant_id = 0) const uint STEP = 0u;

#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_depth) readonly buffer Depth {
  float depth[];  // P.geometry.x floats per pixel, the virtual point depth at P.geometry.y; <= 0: none
};

#define SVGF_GEO_ACCESS
#include "denoise/svgf_common.glsl"

float input_depth(ivec2 q) {
  float d = depth[(uint(q.y) * P.size.x + uint(q.x)) * P.geometry.x + P.geometry.y];
  // Zero, negative and non-finite depths all mean "none".
  return svgf_finite(vec4(d)) && d > 0.0f ? d : 0.0f;
}

bool inside(ivec2 q) {
  return all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, ivec2(P.size.xy)));
}

float depth_of(ivec2 q) {
  return inside(q) ? uintBitsToFloat(geo[uint(q.y) * P.size.x + uint(q.x)].x) : 0.0f;
}

// Of the one-sided differences towards +/-1 along an axis, the one of smaller magnitude (per unit step, +
// direction); 0 where neither neighbour has a depth.
float one_sided(float z, float minus, float plus) {
  bool m = minus > 0.0f, pl = plus > 0.0f;
  if (!m && !pl) return 0.0f;
  if (!m) return plus - z;
  if (!pl) return z - minus;
  return abs(plus - z) < abs(z - minus) ? plus - z : z - minus;
}

void main() {
  ivec2 pix = ivec2(gl_GlobalInvocationID.xy);
  if (!inside(pix)) return;
  uint p = uint(pix.y) * P.size.x + uint(pix.x);
  if (STEP == 0u) {
    prev_geo[p] = uintBitsToFloat(geo[p].x);
    float v[9];
    uint n = 0u;
    if (input_depth(pix) > 0.0f) {
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          ivec2 q = pix + ivec2(dx, dy);
          if (!inside(q)) continue;
          float d = input_depth(q);
          if (d <= 0.0f) continue;
          // Insertion into the sorted prefix.
          uint i = n;
          while (i > 0u && v[i - 1u] > d) {
            v[i] = v[i - 1u];
            --i;
          }
          v[i] = d;
          ++n;
        }
    }
    float z = n == 0u ? 0.0f : ((n & 1u) != 0u ? v[n / 2u] : 0.5f * (v[n / 2u - 1u] + v[n / 2u]));
    geo[p].x = floatBitsToUint(z);
    return;
  }
  float z = depth_of(pix);
  vec2 dz = vec2(0.0f);
  if (z > 0.0f) {
    dz.x = one_sided(z, depth_of(pix - ivec2(1, 0)), depth_of(pix + ivec2(1, 0)));
    dz.y = one_sided(z, depth_of(pix - ivec2(0, 1)), depth_of(pix + ivec2(0, 1)));
  }
  geo[p].y = packHalf2x16(dz);
}
