// Device-side scene layout, shared with the host (render/ includes this with GLM so both sides agree on
// every offset). Only vec4/ivec4/uvec4/mat4 members: std430 and C++ then have the same layout.
#ifndef HAZE_GPU_SCENE_GLSL
#define HAZE_GPU_SCENE_GLSL

#include "common/gbuffer.glsl"
#include "common/layers.glsl"

struct GpuMedium {
  mat4 world_to_index;
  vec4 albedo_g;   // rgb albedo, w: HG g (clamped)
  vec4 world_min;  // world bounds of the medium (dilated by one voxel); w: density scale
  vec4 world_max;  // w: emission scale
  uvec4 grid;      // x: density grid, y: emission grid (indices into the binding "grids"), z: emission mode
  vec4 emission;   // x: kelvin per grid unit (blackbody)
  vec4 sigma_t_color;  // rgb multipliers of sigma_t (read by the CHROMATIC variant only)
};

struct GpuScene {
  vec4 cam_position;
  vec4 cam_right;  // scaled by tan(fov/2) * aspect
  vec4 cam_up;     // scaled by tan(fov/2)
  vec4 cam_forward;
  uvec4 size;          // width, height, volume samples per camera sample, max scattering depth
  uvec4 counts;        // media, lights, local lights, seed
  vec4 haze_albedo_g;  // rgb albedo, w: g
  vec4 haze_min;       // xyz bounds, w: sigma_t
  vec4 haze_max;
  vec4 env;            // rgb radiance seen by camera rays that leave the scene
  vec4 sun_direction;  // xyz towards the sun (any sun), w: cos of the half angle (1: no visible disk)
  vec4 sun_radiance;   // rgb radiance of the visible disk
  uvec4 maj_res;       // majorant grid resolution; w: max tracking steps per query
  vec4 maj_min;        // world bounds of the majorant grid; w: the VDB media's smallest sigma_t multiplier
  vec4 maj_max;
  vec4 settings;  // x: equi-angular probability, y: Russian roulette threshold, z: pixel jitter (0/1)
  vec4 prev_cam_position;  // the previous frame's camera, for motion vectors
  vec4 prev_cam_right;
  vec4 prev_cam_up;
  vec4 prev_cam_forward;
  uvec4 counts2;  // x: surface instances
  // Distance guiding (guiding/params.hpp; read only by the GUIDING variant). Widths are relative to t_s.
  vec4 guide;        // x: P, y: min width, z: prior width, w: prior count (histogram: y choose P 0/1)
  uvec4 guide_grid;  // x, y: vertices across and down, z: K states per vertex (histogram: floats per
                     // vertex), w: C candidates
  vec4 guide_learn;  // x: vertex spacing in pixels, y: learn (0/1), z: max count N, w: min alpha
  // Chromatic media (read by the CHROMATIC variant only): rgb the haze's sigma_t multipliers, w the largest
  // multiplier of any medium and channel (the majorants' factor).
  vec4 haze_sigma_t_color;
  // The walk's sun lobe (read by the SUN_WALK variant only): x its probability at a medium vertex, y its g.
  vec4 sun_walk;
};

// Per-pixel data lives in vec4 layers, one buffer each (gpu/pixel_layers.hpp), so that every buffer of a
// frame stays within maxStorageBufferRange. On the host a download interleaves them: the offsets below are
// 4 * layer + component, and the layer names (render/frame.hpp) are in layer order.
//
// Accumulation, sums then sums of squares: acc_l (L, T), acc_l2 (L², T²), acc_vol (volume term, depth),
// acc_vol2 (its squares), acc_surf (surface term, and the samples dropped for a non-finite radiance:
// ACC_DROPPED), acc_surf2 (its squares), acc_demod, acc_demod2 (the surface term divided by the albedo of
// the first surface hit, per sample: the surface denoiser's input) and acc_vp, the virtual point sums: VP_WT
// and VP_W are sum(Y t) and sum(Y) over the distance samples (Y: luminance of each one's volume
// contribution); VP_G and VP_GN sum the mean of the guide state each sample chose, and count them;
// acc_emit, the emission of the camera's surface hits (kept out of acc_demod: the denoiser adds it back
// after remodulation).
const uint ACC_L = 0u, ACC_T = 3u, ACC_L2 = 4u, ACC_T2 = 7u, ACC_VOL = 8u, ACC_DEPTH = 11u;
const uint ACC_VOL2 = 12u, ACC_SURF = 16u, ACC_SURF2 = 20u, ACC_DEMOD = 24u, ACC_DEMOD2 = 28u;
const uint ACC_VP_WT = 32u, ACC_VP_W = 33u, ACC_VP_G = 34u, ACC_VP_GN = 35u;
const uint ACC_EMIT = 36u;
const uint ACC_DROPPED = 19u;
const uint ACC_STRIDE = 40u;

// Resolved means: out_l (L, depth), out_vol (volume term, virtual point depth: 0 where none), out_surf
// (surface term, transmittance), out_var (sample variance of L), out_demod, out_demod_m2 (the demodulated
// surface term and its second moment), out_emit (the camera hits' emission).
const uint OUT_L = 0u, OUT_DEPTH = 3u, OUT_VOL = 4u, OUT_VPDEPTH = 7u, OUT_SURF = 8u, OUT_T = 11u;
const uint OUT_VAR = 12u, OUT_DEMOD = 16u, OUT_DEMOD_M2 = 20u;
const uint OUT_EMIT = 24u;
const uint OUT_STRIDE = 28u;

// Counters of one frame (the binding "counters"), each a 64-bit count in two uints (low, high): samples
// whose radiance was not finite (dropped: not counted as samples of their pixel, ACC_DROPPED), samples with
// a square clamped at SQUARE_MAX so that the sums of squares of 2^24 samples stay finite in float (the
// second moments of such pixels are then lower bounds), samples in which a tracking query stopped at the
// step cap (its transmittance taken as 0, its collision as none: biased), samples in which sigma_t exceeded
// the majorant at a lookup (biased); then what the trackers did: density lookups, delta tracking's real and
// null collisions, distance samples on camera rays and how many of them the guide drew.
const uint COUNT_NON_FINITE = 0u, COUNT_CLAMPED_SQUARES = 1u, COUNT_STEP_CAP = 2u, COUNT_MAJORANT = 3u;
const uint COUNT_LOOKUPS = 4u, COUNT_DELTA_REAL = 5u, COUNT_DELTA_NULL = 6u, COUNT_DISTANCE = 7u;
const uint COUNT_GUIDED = 8u, COUNTERS = 9u;
const float SQUARE_MAX = 2.0e31;  // FLT_MAX / 2^24

#ifndef __cplusplus
// The frame's scene block, in every kernel that declares the binding "scene".
#ifdef BINDING_scene
layout(std430, binding = BINDING_scene) readonly buffer SceneBuffer {
  GpuScene scene;
};
#endif
#endif

#endif
