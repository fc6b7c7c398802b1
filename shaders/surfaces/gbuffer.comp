#version 460
// The G-buffer (docs/rendering.md, conventions) from the ray through each pixel centre: linear depth, its
// gradient (on the hit's plane), the shading normal, albedo, instance id and motion (previous pixel
// position - current). Without surfaces only the camera's own motion is left: directions at infinity
// reprojected into the previous camera.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8, local_size_y = 8) in;

#include "common/camera.glsl"
#include "common/compat.glsl"
#include "common/packing.glsl"
#define GBUFFER_ACCESS writeonly
#include "volume/gpu_scene.glsl"
#if HAZE_SURFACES
#include "surfaces/material.glsl"
#endif

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  uint W = scene.size.x, H = scene.size.y;
  if (pix.x >= W || pix.y >= H) return;
  vec2 size = vec2(W, H);
  vec2 centre = vec2(pix) + 0.5f;
  vec3 o = scene.cam_position.xyz;
  vec3 d = camera_direction(scene.cam_right.xyz, scene.cam_up.xyz, scene.cam_forward.xyz, centre, size);

  float depth = 0.0f, ddx = 0.0f, ddy = 0.0f;
  vec3 n = -d;
  vec3 albedo = vec3(0.0f);
  uint instance = 0xffffffffu;
  float prev_depth = 0.0f;
  vec2 prev = camera_project_direction(scene.prev_cam_right.xyz, scene.prev_cam_up.xyz,
                                       scene.prev_cam_forward.xyz, d, size);
#if HAZE_SURFACES
  BvhHit h = bvh_closest_hit(o, d, 0.0f, T_INF);
  if (h.triangle != BVH_NONE) {
    depth = h.t;
    vec3 X = o + d * h.t;
    vec3 ng = dot(h.normal, d) < 0.0f ? h.normal : -h.normal;
    n = surface_normal(h, ng);  // the shading normal
    // Depth of the neighbours' rays on the hit plane: exact for planar neighbourhoods.
    vec3 dx = camera_direction(scene.cam_right.xyz, scene.cam_up.xyz, scene.cam_forward.xyz,
                               centre + vec2(1, 0), size);
    vec3 dy = camera_direction(scene.cam_right.xyz, scene.cam_up.xyz, scene.cam_forward.xyz,
                               centre + vec2(0, 1), size);
    float nx = dot(ng, dx), ny = dot(ng, dy), nX = dot(ng, X - o);
    ddx = nx < -1e-6f ? nX / nx - depth : 0.0f;
    ddy = ny < -1e-6f ? nX / ny - depth : 0.0f;
    GpuInstance inst = instances[h.instance];
    albedo = surface_albedo(h);
    instance = h.instance;
    vec3 X_prev = (inst.world_to_prev_world * vec4(X, 1.0f)).xyz;
    prev_depth = length(X_prev - scene.prev_cam_position.xyz);
    prev = camera_project_direction(scene.prev_cam_right.xyz, scene.prev_cam_up.xyz,
                                    scene.prev_cam_forward.xyz, X_prev - scene.prev_cam_position.xyz, size);
  }
#endif
  vec2 motion = prev - centre;
  if (any(isnan(motion)) || any(isinf(motion))) motion = vec2(0.0f);
  uint p = pix.y * W + pix.x;
  g_depth[p] = vec4(depth, ddx, ddy, prev_depth);
  g_normal[p] = vec4(oct_encode(n), motion);
  g_albedo[p] = vec4(albedo, uintBitsToFloat(instance));
}
