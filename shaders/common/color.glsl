// Colour helpers shared by the renderer and the CPU tests.
#ifndef HAZE_COLOR_GLSL
#define HAZE_COLOR_GLSL
#include "common/compat.glsl"

// Rec.709 / sRGB-primaries luminance (docs/rendering.md, conventions; the seed's reference used Rec.601).
HAZE_INLINE float luminance(vec3 c) {
  return dot(c, vec3(0.2126f, 0.7152f, 0.0722f));
}

// Planck's law at wavelength lambda_nm, relative to a 6500 K emitter at 550 nm, so that the scale
// parameter of a blackbody medium reads as "radiance of a 6500 K body".
HAZE_INLINE float planck_relative(float lambda_nm, float kelvin) {
  const float c2 = 1.4387769e7f;  // h c / k in nm K
  float l = lambda_nm / 550.0f;
  float num = 1.0f / (l * l * l * l * l);
  // exp(c2/(550*6500)) - 1 for the reference
  const float ref = 54.9552f;
  float e = exp(min(c2 / (lambda_nm * max(kelvin, 1.0f)), 80.0f)) - 1.0f;
  return num * ref / e;
}

HAZE_INLINE vec3 blackbody_rgb(float kelvin) {
  if (kelvin <= 0.0f) return vec3(0.0f);
  return vec3(planck_relative(610.0f, kelvin), planck_relative(550.0f, kelvin),
              planck_relative(465.0f, kelvin));
}

// Narkowicz's ACES filmic fit.
HAZE_INLINE vec3 tonemap_aces(vec3 x) {
  x = max(x, vec3(0.0f)) * 0.6f;
  return clamp((x * (2.51f * x + 0.03f)) / (x * (2.43f * x + 0.59f) + 0.14f), vec3(0.0f), vec3(1.0f));
}

HAZE_INLINE vec3 tonemap_reinhard(vec3 x) {
  x = max(x, vec3(0.0f));
  return x / (vec3(1.0f) + x);
}

HAZE_INLINE float srgb_encode(float c) {
  c = clamp(c, 0.0f, 1.0f);
  return c <= 0.0031308f ? 12.92f * c : 1.055f * pow(c, 1.0f / 2.4f) - 0.055f;
}

// The preview's tone curves: 0 ACES fit, 1 Reinhard, 2 clamp (render.tonemap).
HAZE_INLINE vec3 tonemap(vec3 x, uint op) {
  return op == 0u ? tonemap_aces(x) : (op == 1u ? tonemap_reinhard(x) : clamp(x, vec3(0.0f), vec3(1.0f)));
}

// Inverse of srgb_encode: an sRGB-encoded value in [0, 1] to linear.
HAZE_INLINE float srgb_decode(float c) {
  c = clamp(c, 0.0f, 1.0f);
  return c <= 0.04045f ? c / 12.92f : pow((c + 0.055f) / 1.055f, 2.4f);
}

// A tonemapped colour in [0, 1] as sRGB-encoded RGBA8 (alpha 255), red in the low byte.
HAZE_INLINE uint pack_srgb8(vec3 m) {
  uvec3 c8 = uvec3(round(vec3(srgb_encode(m.r), srgb_encode(m.g), srgb_encode(m.b)) * 255.0f));
  return c8.r | (c8.g << 8u) | (c8.b << 16u) | (255u << 24u);
}

#endif
