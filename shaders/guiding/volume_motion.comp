#version 460
// Volume motion vectors (docs/guiding.md): the previous frame's virtual points projected forward into
// this frame's camera. Two pipelines of this source (specialization constant RESOLVE):
//  splat (0), one thread per previous pixel p: its point X = previous camera + d(p) * ray(p), moved by its
//    medium (its transform, and with HAZE_VELOCITY the velocity grid at X), lands on pixel q of the current
//    camera; atomicMin of (distance bits << 32 | p) into keys[q].
//    Positive floats order as their bits, so the nearest point wins whatever the thread order, and equal
//    distances go to the lower source index: the result is deterministic.
//  resolve (1), one thread per current pixel: decodes its winner and recomputes that point (a gather, so
//    every pixel is written once), or falls back to the G-buffer's surface motion.
//  backward (2), the baseline the forward projection is measured against: each current pixel's own virtual
//    point (this frame's depth, in prev_depth) projected into the previous camera; camera motion only.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
layout(local_size_x = 8, local_size_y = 8) in;

#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "guiding/volume_motion_layout.glsl"
#include "volume/gpu_scene.glsl"

layout(constant_id = 0) const uint RESOLVE = 0u;
#if HAZE_VELOCITY
#include "common/compat.glsl"
#include "volume/grids.glsl"
#endif

layout(std430, binding = BINDING_prev_depth) readonly buffer PrevDepth {
  float prev_depth[];  // the previous frame's virtual point distance along the pixel-centre ray; 0: none
};
#ifdef BINDING_media_motion
layout(std430, binding = BINDING_media_motion) readonly buffer Media {
  MediumMotion media_motion[];  // pc.media_count of them: the media that moved
};
#endif
layout(std430, binding = BINDING_keys) buffer Keys {
  uint64_t keys[];  // per current pixel; all ones: no point landed
};
layout(std430, binding = BINDING_motion) writeonly buffer Motion {
  vec4 motion[];
};

layout(push_constant) uniform Push {
  uvec2 size;                       // width, height (of both frames)
  uint depth_stride, depth_offset;  // prev_depth: floats per pixel and the depth's offset
  uint media_count;
}
pc;

const uint64_t KEY_NONE = 0xffffffffffffffffUL;

// The virtual point of previous pixel p seen from the current camera: v = X - camera position, q its
// continuous image position. False when p has no point or it falls behind the camera or off screen.
bool project_point(uint p, out float d, out vec3 v, out vec2 q) {
  d = prev_depth[p * pc.depth_stride + pc.depth_offset];
  // Bit test rather than comparisons: zero, negative, infinite and NaN depths all mean "no point", also
  // where the compiler assumes finite maths.
  uint bits = floatBitsToUint(d);
  if (bits == 0u || bits >= 0x7f800000u) return false;
  vec2 size = vec2(pc.size);
  vec2 centre = vec2(p % pc.size.x, p / pc.size.x) + 0.5f;
  vec3 X = scene.prev_cam_position.xyz + d * camera_direction(scene.prev_cam_right.xyz, scene.prev_cam_up.xyz,
                                                              scene.prev_cam_forward.xyz, centre, size);
#ifdef BINDING_media_motion
  for (uint i = 0u; i < pc.media_count; ++i) {
    MediumMotion m = media_motion[i];
    if (all(greaterThanEqual(X, m.prev_min.xyz)) && all(lessThanEqual(X, m.prev_max.xyz))) {
      vec3 moved = (m.prev_world_to_world * vec4(X, 1.0f)).xyz;
#if HAZE_VELOCITY
      if (m.velocity.w != 0u) {
        // Forward Euler over the frame with the previous frame's velocity at the point.
        vec3 vel = vec3(0.0f);
        [[dont_unroll]] for (int c = 0; c < 3; ++c) {
          vel[c] = grid_trilinear(m.velocity[c], (m.prev_world_to_velocity[c] * vec4(X, 1.0f)).xyz);
        }
        moved += (m.velocity_to_world * vec4(vel, 0.0f)).xyz;
      }
#endif
      X = moved;
      break;
    }
  }
#endif
  v = X - scene.cam_position.xyz;
  if (!(dot(v, scene.cam_forward.xyz) > 0.0f)) return false;
  q = camera_project_direction(scene.cam_right.xyz, scene.cam_up.xyz, scene.cam_forward.xyz, v, size);
  return all(greaterThanEqual(q, vec2(0.0f))) && all(lessThan(q, size));
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  if (pix.x >= pc.size.x || pix.y >= pc.size.y) return;
  uint p = pix.y * pc.size.x + pix.x;
  float d;
  vec3 v;
  vec2 q;
  if (RESOLVE == 2u) {
    d = prev_depth[p * pc.depth_stride + pc.depth_offset];
    uint bits = floatBitsToUint(d);
    vec2 size = vec2(pc.size), centre = vec2(pix) + 0.5f;
    if (bits != 0u && bits < 0x7f800000u) {
      vec3 X = scene.cam_position.xyz + d * camera_direction(scene.cam_right.xyz, scene.cam_up.xyz,
                                                             scene.cam_forward.xyz, centre, size);
      v = X - scene.prev_cam_position.xyz;
      if (dot(v, scene.prev_cam_forward.xyz) > 0.0f) {
        q = camera_project_direction(scene.prev_cam_right.xyz, scene.prev_cam_up.xyz,
                                     scene.prev_cam_forward.xyz, v, size);
        if (all(greaterThanEqual(q, vec2(0.0f))) && all(lessThan(q, size))) {
          motion[p] = vec4(q - centre, d - length(v), 1.0f);
          return;
        }
      }
    }
    motion[p] = vec4(g_normal[p].zw, 0.0f, 0.0f);
    return;
  }
  // One call of project_point (one grid lookup site with HAZE_VELOCITY): the splat projects p, the resolve
  // its winner.
  uint64_t key = RESOLVE == 0u ? 0UL : keys[p];
  uint src = RESOLVE == 0u ? p : uint(key & 0xffffffffUL);
  bool landed = key != KEY_NONE && project_point(src, d, v, q);
  if (RESOLVE == 0u) {
    if (!landed) return;
    uvec2 t = uvec2(q);  // floor: q >= 0
    atomicMin(keys[t.y * pc.size.x + t.x], packUint2x32(uvec2(p, floatBitsToUint(length(v)))));
    return;
  }
  if (landed) {
    vec2 centre = vec2(src % pc.size.x, src / pc.size.x) + 0.5f;
    motion[p] = vec4(centre - q, length(v) - d, 1.0f);
  } else {
    motion[p] = vec4(g_normal[p].zw, 0.0f, 0.0f);
  }
}
