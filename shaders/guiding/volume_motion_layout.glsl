// Volume motion vectors (docs/guiding.md), shared with the host (guiding/volume_motion.hpp). Only
// vec4/mat4 members: std430 and C++ then have the same layout.
#ifndef HAZE_VOLUME_MOTION_LAYOUT_GLSL
#define HAZE_VOLUME_MOTION_LAYOUT_GLSL

// How one medium moved between the previous frame and this one: a virtual point X inside
// [prev_min, prev_max] (previous frame's world bounds) moves to prev_world_to_world * X, plus, for a medium
// with a velocity grid (velocity.w = 1), velocity_to_world * v(X): v's component c is the trilinear value of
// grid velocity[c] (an index into the binding "grids") at prev_world_to_velocity[c] * X. The first medium
// of the list that contains a point moves it.
struct MediumMotion {
  mat4 prev_world_to_world;
  vec4 prev_min;  // xyz
  vec4 prev_max;  // xyz
  mat4 prev_world_to_velocity[3];  // previous world -> index space of velocity component c's grid
  mat4 velocity_to_world;          // grid vector -> world displacement over the frame (scale, 1/fps, transform)
  uvec4 velocity;                  // xyz: the component grids; w: 1 when the medium has a velocity
};

// Output per pixel (vec4): xy previous pixel position - current one, z distance of the point from this
// frame's camera minus its distance from the previous one, w 1 where a point landed (0: xy is the G-buffer's
// surface motion, z 0).

#endif
