// Counter-based random numbers: a PCG hash seeds a per-sample state that a PCG step advances
// (Jarzynski and Olano 2020). Deterministic for a (seed, pixel, sample) triple.
#ifndef HAZE_RNG_GLSL
#define HAZE_RNG_GLSL
#include "common/compat.glsl"

HAZE_INLINE uint pcg_hash(uint v) {
  uint state = v * 747796405u + 2891336453u;
  uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
  return (word >> 22u) ^ word;
}

HAZE_INLINE uint rng_init(uint seed, uint pixel, uint sample_index) {
  return pcg_hash(seed ^ pcg_hash(pixel ^ pcg_hash(sample_index + 0x9e3779b9u)));
}

HAZE_INLINE uint rng_next_uint(INOUT(uint) state) {
  state = state * 747796405u + 2891336453u;
  uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
  return (word >> 22u) ^ word;
}

// Uniform in [0, 1): 24 random bits so that 1 is never returned.
HAZE_INLINE float rng_next(INOUT(uint) state) {
  return float(rng_next_uint(state) >> 8u) * (1.0f / 16777216.0f);
}

#endif
