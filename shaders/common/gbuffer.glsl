// The G-buffer (docs/rendering.md, conventions), shared by the G-buffer pass, the denoisers and the host.
#ifndef HAZE_GBUFFER_GLSL
#define HAZE_GBUFFER_GLSL

// From the ray through each pixel centre, as three vec4 layers (gpu/pixel_layers.hpp): g_depth (depth,
// its change at the +x and +y neighbours' rays on the hit plane, the point's distance from the previous
// camera), g_normal (octahedral-encoded normal facing the camera, motion), g_albedo (albedo, instance id
// as float bits). Host offsets into an interleaved download (4 * layer + component):
const uint G_DEPTH = 0u;       // Euclidean distance to the first surface; 0: none
const uint G_DDEPTH = 1u;      // depth at the +x and +y neighbours' rays on the hit plane minus depth
const uint G_PREV_DEPTH = 3u;  // distance of the same surface point from the previous camera; 0: none
const uint G_NORMAL = 4u;      // octahedral-encoded normal, facing the camera
const uint G_MOTION = 6u;      // previous pixel position - current pixel position
const uint G_ALBEDO = 8u;      // rgb
const uint G_INSTANCE = 11u;   // instance id as float bits; 0xffffffff: none
const uint G_STRIDE = 12u;

// Demodulation divides the surface signal by max(albedo, DEMOD_MIN_ALBEDO) (1 where no surface is hit).
const float DEMOD_MIN_ALBEDO = 1e-3;

#ifndef __cplusplus
// The layers of this frame that the kernel declares (g_depth, g_normal, g_albedo; read-only unless the
// kernel defines GBUFFER_ACCESS first) and all three of the previous frame (prev_g_depth, prev_g_normal,
// prev_g_albedo).
#ifndef GBUFFER_ACCESS
#define GBUFFER_ACCESS readonly
#endif
#ifdef BINDING_g_depth
layout(std430, binding = BINDING_g_depth) GBUFFER_ACCESS buffer GDepth {
  vec4 g_depth[];
};
#endif
#ifdef BINDING_g_normal
layout(std430, binding = BINDING_g_normal) GBUFFER_ACCESS buffer GNormal {
  vec4 g_normal[];
};
#endif
#ifdef BINDING_g_albedo
layout(std430, binding = BINDING_g_albedo) GBUFFER_ACCESS buffer GAlbedo {
  vec4 g_albedo[];
};
#endif
#ifdef BINDING_prev_g_depth
layout(std430, binding = BINDING_prev_g_depth) readonly buffer PrevGDepth {
  vec4 prev_g_depth[];
};
layout(std430, binding = BINDING_prev_g_normal) readonly buffer PrevGNormal {
  vec4 prev_g_normal[];
};
layout(std430, binding = BINDING_prev_g_albedo) readonly buffer PrevGAlbedo {
  vec4 prev_g_albedo[];
};
#endif
#endif

#endif
