// Helpers shared by the SVGF passes (denoise/svgf.cpp declares and runs them). The parameter block P is
// declared here; the G-buffer helpers read the layers of common/gbuffer.glsl that the kernel declares.
#ifndef HAZE_SVGF_COMMON_GLSL
#define HAZE_SVGF_COMMON_GLSL

#include "common/color.glsl"
#include "common/gbuffer.glsl"
#include "common/packing.glsl"
#include "denoise/svgf_layout.glsl"

layout(std430, binding = BINDING_params) readonly buffer Params {
  SvgfGpuParams P;
};

// Integer test: fast-math compilers may fold isnan/isinf away, bits they cannot.
bool svgf_finite(vec4 v) {
  uvec4 e = floatBitsToUint(v) & 0x7f800000u;
  return all(notEqual(e, uvec4(0x7f800000u)));
}

vec4 unpack_half4(uvec2 w) {
  return vec4(unpackHalf2x16(w.x), unpackHalf2x16(w.y));
}

// Non-finite values become 0; the rest saturate at the half-float range.
uvec2 pack_half4(vec4 v) {
  if (!svgf_finite(v)) v = vec4(0.0f);
  v = clamp(v, vec4(-SVGF_HALF_MAX), vec4(SVGF_HALF_MAX));
  return uvec2(packHalf2x16(v.xy), packHalf2x16(v.zw));
}

float linstep(float a, float b, float x) {
  return b > a ? clamp((x - a) / (b - a), 0.0f, 1.0f) : (x >= b ? 1.0f : 0.0f);
}

// What the passes need of a G-buffer pixel.
struct GPixel {
  float z;  // 0: no surface
  vec2 dz;  // depth change towards +x and +y
  vec3 n;
  vec3 albedo;
  uint id;
  float z_prev;  // distance of this point from the previous camera (0: unknown)
};

GPixel g_unpack(vec4 depth, vec4 normal, vec4 albedo) {
  GPixel g;
  g.z = depth.x;
  g.dz = depth.yz;
  g.z_prev = depth.w;
  g.n = oct_decode(normal.xy);
  g.albedo = albedo.rgb;
  g.id = floatBitsToUint(albedo.w);
  return g;
}

#ifdef BINDING_g_depth
GPixel g_load(uint p) {
  return g_unpack(g_depth[p], g_normal[p], g_albedo[p]);
}
#endif
#ifdef BINDING_prev_g_depth
GPixel g_load_prev(uint p) {
  return g_unpack(prev_g_depth[p], prev_g_normal[p], prev_g_albedo[p]);
}
#endif

// The albedo the surface signal was divided by (shaders/volume/trace.comp): 1 where no surface was hit.
vec3 demod_albedo(GPixel g) {
  return g.z > 0.0f ? max(g.albedo, vec3(DEMOD_MIN_ALBEDO)) : vec3(1.0f);
}

// Edge-stopping depth term of Schied et al. 2017: the depth difference against what the centre's depth
// gradient predicts over the offset, scaled by phi.
float depth_weight(GPixel c, GPixel q, vec2 offset, float phi) {
  if (c.z <= 0.0f || q.z <= 0.0f) return c.z <= 0.0f && q.z <= 0.0f ? 1.0f : 0.0f;
  float predicted = abs(dot(c.dz, offset));
  return exp(-abs(c.z - q.z) / (phi * predicted + 1e-3f * c.z));
}

#endif
