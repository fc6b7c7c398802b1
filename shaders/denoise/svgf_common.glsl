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

#ifdef SVGF_OWN_GEOMETRY
// The instance's own geometry (geometry.comp) instead of the surface G-buffer: per pixel the virtual point
// depth and its gradient (geo: depth bits, packHalf2x16(gradient)) and the previous frame's depth. A virtual
// point has no normal, albedo or instance: every normal test passes.
#ifndef SVGF_GEO_ACCESS
#define SVGF_GEO_ACCESS readonly
#endif
layout(std430, binding = BINDING_geo) SVGF_GEO_ACCESS buffer Geo {
  uvec2 geo[];
};
layout(std430, binding = BINDING_prev_geo) SVGF_GEO_ACCESS buffer PrevGeo {
  float prev_geo[];
};

GPixel g_point(float z, vec2 dz) {
  GPixel g;
  g.z = z;
  g.dz = dz;
  g.z_prev = 0.0f;
  g.n = vec3(0.0f, 0.0f, 1.0f);
  g.albedo = vec3(1.0f);
  g.id = 0u;
  return g;
}

GPixel g_load(uint p) {
  uvec2 w = geo[p];
  return g_point(uintBitsToFloat(w.x), unpackHalf2x16(w.y));
}

GPixel g_load_prev(uint p) {
  return g_point(prev_geo[p], vec2(0.0f));
}

// A tap of the spatial passes: the geometry is one 8-byte word already.
GPixel g_load_tap(uint p) {
  return g_load(p);
}
#else
#ifdef BINDING_g_depth
GPixel g_load(uint p) {
  return g_unpack(g_depth[p], g_normal[p], g_albedo[p]);
}
#endif
#ifdef BINDING_gpack
// What the spatial passes (variance, filter) read at their taps, packed by the accumulation pass into one
// 8-byte word per pixel: depth (f32 bits) and the octahedral normal (2 x snorm16). A tap then reads 8 bytes
// instead of two 16-byte G-buffer layers, which is what the filter's time follows on lavapipe at the large
// gaps (cache misses). Taps carry no depth gradient, albedo or instance: only the centre's are used, except
// by the splat normalization's symmetric weight, which reads the gradient from the G-buffer.
#ifndef SVGF_GPACK_ACCESS
#define SVGF_GPACK_ACCESS readonly
#endif
layout(std430, binding = BINDING_gpack) SVGF_GPACK_ACCESS buffer GPack {
  uvec2 gpack[];
};

uvec2 g_pack(vec4 depth, vec4 normal) {
  return uvec2(floatBitsToUint(depth.x), packSnorm2x16(normal.xy));
}

GPixel g_load_tap(uint p) {
  uvec2 w = gpack[p];
  GPixel g;
  g.z = uintBitsToFloat(w.x);
#if defined(SVGF_SPLAT) && defined(BINDING_g_depth)
  g.dz = g_depth[p].yz;
#else
  g.dz = vec2(0.0f);
#endif
  g.z_prev = 0.0f;
  g.n = oct_decode(unpackSnorm2x16(w.y));
  g.albedo = vec3(1.0f);
  g.id = 0u;
  return g;
}
#endif
#ifdef BINDING_prev_g_depth
GPixel g_load_prev(uint p) {
  return g_unpack(prev_g_depth[p], prev_g_normal[p], prev_g_albedo[p]);
}
#endif
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

// A filter tap's centre as the edge-stopping terms see it (filter.comp): its geometry, luminance and sigma,
// the scale of its luminance term (phi_l sigma + eps) and how far its depth and normal terms have faded.
struct FilterCentre {
  GPixel g;
  float Y, sigma, luminance_scale, fade_n, fade_z;
  vec2 across;  // SVGF_EPIPOLAR: unit normal of the pixel's epipolar line over the term's width (0: none)
};

#ifdef SVGF_EPIPOLAR
// In-scattered light from one light varies slowly along an epipolar line, the image of a plane through the
// camera and the light: every ray in that plane crosses the same shadow boundaries, which are lines towards
// the light. Across the line it changes abruptly (the sheets of a light shaft). P.epipole holds the light's
// image.

// The epipolar line's unit direction at the pixel position `pix`; 0 at the light's image itself, where every
// direction is an epipolar line.
vec2 epipolar_along(vec2 pix) {
  vec2 along = P.epipole.xy - pix * P.epipole.w;
  float len = length(along);
  return len > 1e-4f * abs(P.epipole.w) && len > 0.0f ? along / len : vec2(0.0f);
}

// The line's unit normal at `pix` divided by the filter term's width.
vec2 epipolar_across(vec2 pix) {
  vec2 along = epipolar_along(pix);
  return vec2(-along.y, along.x) / P.epipole.z;
}
#endif

FilterCentre filter_centre(GPixel g, float Y, float sigma, vec2 pix) {
  FilterCentre c;
#ifdef SVGF_EPIPOLAR
  c.across = epipolar_across(pix);
#else
  c.across = vec2(0.0f);
#endif
  c.g = g;
  c.Y = Y;
  c.sigma = sigma;
  c.luminance_scale = P.filter_phi.x * sigma + P.filter_phi.w;
  c.fade_n = P.filter_fade.x > 0.0f ? smoothstep(0.0f, P.filter_fade.x, g.z) : 0.0f;
  c.fade_z = P.filter_fade.y > 0.0f ? smoothstep(0.0f, P.filter_fade.y, g.z) : 0.0f;
  return c;
}

// luminance_sigma "pair": the luminance term's scale from the spread of the difference Y_q - Y_p itself,
// phi_l sqrt((sigma_p^2 + sigma_q^2) / 2) + eps, the same both ways. With the centre's sigma alone, a dark
// centre of skewed noise (small sigma) refuses its bright neighbours while they take it in, and the gather
// normalization loses energy.
float pair_luminance_scale(float sigma_p, float sigma_q) {
  return P.filter_phi.x * sqrt(0.5f * (sigma_p * sigma_p + sigma_q * sigma_q)) + P.filter_phi.w;
}

// Adaptive mode's edge-stopping weight of tap q (luminance Yq, at offset o in pixels) for centre c, without
// the kernel's own weight: exp(-(|dY| / luminance_scale)^2) times the depth and normal terms, each faded
// towards 1 with the centre's distance, and with SVGF_EPIPOLAR exp(-(e / width)^2), e the tap's distance from
// the centre's epipolar line.
float filter_weight(FilterCentre c, GPixel q, float Yq, float luminance_scale, vec2 o) {
  float x = abs(Yq - c.Y) / luminance_scale, x2 = x * x;
  float wz = mix(depth_weight(c.g, q, o, P.filter_phi.y), 1.0f, c.fade_z);
  float wn = mix(smoothstep(P.filter_phi.z, 1.0f, dot(c.g.n, q.n)), 1.0f, c.fade_n);
#ifdef SVGF_EPIPOLAR
  float e = dot(o, c.across);  // the tap's distance from the centre's epipolar line over the width
  x2 += e * e;
#endif
  return exp(-x2) * wz * wn;
}

// The same weight made symmetric, the geometric mean of the weights each way: what the energy-conserving
// (splat) normalization needs, w(c, q) = w(q, c).
float filter_weight_symmetric(FilterCentre c, FilterCentre q, vec2 o, bool pair) {
  float scale_c = pair ? pair_luminance_scale(c.sigma, q.sigma) : c.luminance_scale;
  float scale_q = pair ? scale_c : q.luminance_scale;
  return sqrt(filter_weight(c, q.g, q.Y, scale_c, o) * filter_weight(q, c.g, c.Y, scale_q, -o));
}

// History test on the signal itself (adaptive mode, reproject.w = k > 0): the history's mean luminance Y_h
// against this frame's mean over the neighbours, mean_n, with var_h and var_mean the variances of the two
// estimates. Past a 10% tolerance, a difference of more than k of their combined standard errors means the
// history shows something else (the volume instance: one virtual point per pixel stands for several sheets
// and moves the others with the wrong depth). Returns how far to cut the history: 0 below k, 1 past 2k.
float history_test(float Y_h, float var_h, float mean_n, float var_mean) {
  float k = P.reproject.w;
  if (k <= 0.0f) return 0.0f;
  float d = max(abs(Y_h - mean_n) - 0.1f * max(Y_h, mean_n), 0.0f);
  float z = d / (sqrt(max(var_h, 0.0f) + max(var_mean, 0.0f)) + 1e-6f * max(Y_h, mean_n) + 1e-12f);
  return linstep(k, 2.0f * k, z);
}

#endif
