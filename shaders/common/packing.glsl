// Packing of G-buffer values, shared by the shaders and the CPU tests.
#ifndef HAZE_PACKING_GLSL
#define HAZE_PACKING_GLSL
#include "common/compat.glsl"

// Octahedral normal encoding (Cigolle et al. 2014): a unit vector to [-1, 1]^2 and back.
HAZE_INLINE vec2 oct_wrap(vec2 v) {
  return (vec2(1.0f) - abs(vec2(v.y, v.x))) * vec2(v.x >= 0.0f ? 1.0f : -1.0f, v.y >= 0.0f ? 1.0f : -1.0f);
}

HAZE_INLINE vec2 oct_encode(vec3 n) {
  n /= (abs(n.x) + abs(n.y) + abs(n.z));
  vec2 p = vec2(n.x, n.y);
  return n.z >= 0.0f ? p : oct_wrap(p);
}

HAZE_INLINE vec3 oct_decode(vec2 e) {
  vec3 n = vec3(e.x, e.y, 1.0f - abs(e.x) - abs(e.y));
  float t = max(-n.z, 0.0f);
  n.x += n.x >= 0.0f ? -t : t;
  n.y += n.y >= 0.0f ? -t : t;
  return normalize(n);
}

#endif
