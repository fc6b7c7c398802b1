// SVGF per-instance parameters as the shaders read them, shared with the host (denoise/svgf.cpp fills it
// from denoise/params.hpp). Only vec4/uvec4 members: std430 and C++ then have the same layout.
#ifndef HAZE_SVGF_LAYOUT_GLSL
#define HAZE_SVGF_LAYOUT_GLSL

struct SvgfGpuParams {
  uvec4 size;        // width, height, percentile blocks x, y
  uvec4 layout_in;   // colour: float stride and offset per pixel; motion: stride, offset
  uvec4 flags;       // x: remodulate by albedo (1) or not (0); y, z: emission stride, offset (SVGF_EMISSION)
  vec4 accumulate;   // x: a (alpha = max(1 - a, 1/n)), y: max history, z: adaptivity strength s, w: k_a
  vec4 percentiles;  // firefly low, up; adaptivity low, up (quantiles in [0, 1])
  vec4 firefly;      // x: bias, y: k_f, z: hard clamp (max luminance)
  vec4 reproject;    // x: cos of the normal threshold, y: depth tolerance tau, z: border history cap,
                     // w: k of the history test (0: off)
  vec4 variance;     // x: cos of the normal reject, y: depth accept (phi), z: spatial bias b, w: falloff f
  vec4 filter_phi;   // x: phi_l, y: phi_z, z: cos of phi_n (adaptive) or exponent (classic), w: epsilon
  vec4 filter_fade;  // x: zbias normals, y: zbias depth
  vec4 taa;        // x: blend (weight of the history), y: clamp (0 min/max, 1 mean +- gamma sigma), z: gamma
  uvec4 geometry;  // own geometry (SVGF_OWN_GEOMETRY): x, y: the input depth's float stride and offset
  vec4 variance_scale;  // x: 1 for filter_sigma "estimate" (else 0), y: the smallest alpha, max(1 - a, 1e-3)
  vec4 epipole;  // SVGF_EPIPOLAR: x, y, w the light's image in homogeneous pixel coordinates; z: the width
                 // of the filter's epipolar term in pixels
};

// Per-pixel words of the half-float buffers: uvec2(packHalf2x16(r, g), packHalf2x16(b, a)).
// Moments buffer: float m1, m2, history length n per pixel.
const uint SVGF_MOMENTS_STRIDE = 3u;
// Pixels (a column) per invocation of the variance pass.
const uint SVGF_VARIANCE_ROWS = 8u;
// Largest value stored in half floats (colour and sigma saturate there).
const float SVGF_HALF_MAX = 65000.0;

#endif
