// Pinhole camera: the ray through a point of the image and the image position of a world point. Shared with
// the host tests. right and up are scaled by tan(fov/2) (times the aspect for right); pixel (0, 0) is the
// top-left corner of the image.
#ifndef HAZE_CAMERA_GLSL
#define HAZE_CAMERA_GLSL
#include "common/compat.glsl"

HAZE_INLINE vec3 camera_direction(vec3 right, vec3 up, vec3 forward, vec2 pixel, vec2 size) {
  vec2 ndc = pixel / size * 2.0f - 1.0f;
  return normalize(forward + ndc.x * right - ndc.y * up);
}

// Image position (in pixels) of the direction v from the camera (v = X - position; any length).
HAZE_INLINE vec2 camera_project_direction(vec3 right, vec3 up, vec3 forward, vec3 v, vec2 size) {
  float z = dot(v, forward);
  vec2 ndc = vec2(dot(v, right) / dot(right, right), -dot(v, up) / dot(up, up)) / z;
  return (ndc + 1.0f) * 0.5f * size;
}

#endif
