// G-buffer layout (DESIGN.md section 5), shared by the G-buffer pass, the denoisers and the host.
#ifndef HAZE_GBUFFER_GLSL
#define HAZE_GBUFFER_GLSL

// G-buffer per pixel, from the ray through the pixel centre (DESIGN.md section 5).
const uint G_DEPTH = 0u;        // Euclidean distance to the first surface; 0: none
const uint G_DDEPTH = 1u;       // depth at the +x and +y neighbours' rays on the hit plane minus depth
const uint G_NORMAL = 3u;       // octahedral-encoded normal, facing the camera
const uint G_ALBEDO = 5u;       // rgb
const uint G_INSTANCE = 8u;     // instance id as float bits; 0xffffffff: none
const uint G_MOTION = 9u;       // previous pixel position - current pixel position
const uint G_PREV_DEPTH = 11u;  // distance of the same surface point from the previous camera; 0: none
const uint G_STRIDE = 12u;

// Demodulation divides the surface signal by max(albedo, DEMOD_MIN_ALBEDO) (1 where no surface is hit).
const float DEMOD_MIN_ALBEDO = 1e-3;

#endif
