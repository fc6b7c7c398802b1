// Device-side scene layout, shared with the host (render/ includes this with GLM so both sides agree on
// every offset). Only vec4/ivec4/uvec4/mat4 members: std430 and C++ then have the same layout.
#ifndef HAZE_GPU_SCENE_GLSL
#define HAZE_GPU_SCENE_GLSL

#include "common/gbuffer.glsl"

// Light types in GpuLight.position.w. Local lights come first in the light array.
const uint LIGHT_POINT = 0u;  // point and spot (a point is a spot with no falloff)
const uint LIGHT_SUN = 1u;
const uint LIGHT_ENV = 2u;
const uint LIGHT_TRIANGLE = 3u;  // an emissive surface triangle (two-sided)

struct GpuLight {
  vec4 position;   // xyz position (local), w: type
  vec4 radiance;   // rgb: intensity (local), irradiance (sun), radiance (env)
  vec4 direction;  // xyz: spot axis (local), direction towards the sun
  vec4 params;     // local: x cos_outer, y cos_inner of the spot falloff; sun: x cos of the half angle
};

// Per surface instance: its material and where its points were in the previous frame.
struct GpuInstance {
  vec4 albedo;               // rgb Lambertian reflectance
  vec4 emission;             // rgb emitted radiance
  mat4 world_to_prev_world;  // previous object_to_world * inverse(current object_to_world)
  uvec4 texture;  // albedo texture: x first texel in the texel buffer, y width, z height; w 1 if any
};

struct GpuMedium {
  mat4 world_to_index;
  vec4 albedo_g;   // rgb albedo, w: HG g (clamped)
  vec4 world_min;  // world bounds of the medium (dilated by one voxel); w: density scale
  vec4 world_max;  // w: emission scale
  uvec4 grid;     // x: byte offset of the density grid, y: byte offset of the emission grid, z: emission mode
  vec4 emission;  // x: kelvin per grid unit (blackbody)
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
  vec4 sun_direction;  // xyz towards the sun, w: cos of the half angle (1: no visible disk)
  vec4 sun_radiance;   // rgb radiance of the visible disk
  uvec4 maj_res;       // majorant grid resolution; w: max tracking steps per query
  vec4 maj_min;        // world bounds of the majorant grid
  vec4 maj_max;
  vec4 settings;  // x: equi-angular probability, y: Russian roulette threshold, z: pixel jitter (0/1)
  vec4 prev_cam_position;  // the previous frame's camera, for motion vectors
  vec4 prev_cam_right;
  vec4 prev_cam_up;
  vec4 prev_cam_forward;
  uvec4 counts2;  // x: surface instances
  // Distance guiding (guiding/params.hpp; read only by the GUIDING variant). Widths are relative to t_s.
  vec4 guide;        // x: P, y: min width, z: prior width, w: prior count
  uvec4 guide_grid;  // x, y: vertices across and down, z: K states per vertex, w: C candidates
  vec4 guide_learn;  // x: vertex spacing in pixels, y: learn (0/1), z: max count N, w: min alpha
};

// Accumulation layout per pixel: sums, then sums of squares. SURF_DEMOD is the surface term divided by the
// albedo of the first surface hit, per sample (the surface denoiser's input). The virtual point sums: VP_WT
// and VP_W are sum(Y t) and sum(Y) over the distance samples (Y: luminance of each one's volume
// contribution); VP_G and VP_GN sum the mean of the guide state each sample chose, and count them.
const uint ACC_L = 0u, ACC_VOL = 3u, ACC_SURF = 6u, ACC_T = 9u, ACC_DEPTH = 10u;
const uint ACC_L2 = 11u, ACC_VOL2 = 14u, ACC_SURF2 = 17u, ACC_T2 = 20u;
const uint ACC_DEMOD = 21u, ACC_DEMOD2 = 24u;
const uint ACC_VP_WT = 27u, ACC_VP_W = 28u, ACC_VP_G = 29u, ACC_VP_GN = 30u;
const uint ACC_STRIDE = 31u;

// Resolved output per pixel. VPDEPTH: the virtual point depth (0: none).
const uint OUT_L = 0u, OUT_VOL = 3u, OUT_SURF = 6u, OUT_T = 9u, OUT_DEPTH = 10u, OUT_VAR = 11u;
const uint OUT_DEMOD = 14u, OUT_DEMOD_M2 = 17u, OUT_VPDEPTH = 20u;
const uint OUT_STRIDE = 21u;

#endif
