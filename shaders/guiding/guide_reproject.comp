#version 460
// Temporal reuse of the guiding states (docs/guiding.md): each vertex of this frame's grid takes the K
// states of the previous frame's vertex nearest to where its pixel's virtual point was (the volume motion),
// with the moments shifted by the point's change of distance along the ray. Vertices whose point came from
// outside the previous grid start empty. Histograms (HAZE_GUIDE_HIST) are carried unshifted, in their
// relative units, their sums scaled so that they count at most max_count samples: a histogram is a valid
// pdf wherever it came from, and the recent samples weigh more.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;
#include "common/compat.glsl"
#include "common/dispatch.glsl"
#include "guiding/guide.glsl"
#include "volume/gpu_scene.glsl"

layout(std430, binding = BINDING_motion) readonly buffer Motion {
  vec4 motion[];  // guiding::VolumeMotion output: xy previous - current position, z change of distance
};
#if HAZE_GUIDE_HIST
layout(std430, binding = BINDING_prev_states) readonly buffer PrevStates {
  float prev_states[];
};
layout(std430, binding = BINDING_states) writeonly buffer States {
  float states[];
};
#else
layout(std430, binding = BINDING_prev_states) readonly buffer PrevStates {
  vec4 prev_states[];
};
layout(std430, binding = BINDING_states) writeonly buffer States {
  vec4 states[];
};
#endif

void main() {
  uvec4 G = scene.guide_grid;
  uint i = invocation_index();
  if (i >= G.x * G.y * G.z) return;
  uint v = i / G.z, k = i % G.z;
  float S = scene.guide_learn.x;
  // Vertex (x, y) sits at pixel coordinate (x, y) * S; the pixel there (clamped to the image) moved by m.
  vec2 at = vec2(v % G.x, v / G.x) * S;
  ivec2 pix = clamp(ivec2(floor(at)), ivec2(0), ivec2(scene.size.xy) - 1);
  vec4 m = motion[uint(pix.y) * scene.size.x + uint(pix.x)];
  vec2 from = round((at + m.xy) / S);
#if HAZE_GUIDE_HIST
  // G.z: floats per vertex; k: which float.
  const uint B = HAZE_GUIDE_BINS;
  float s = 0.0f;
  if (all(greaterThanEqual(from, vec2(0.0f))) && all(lessThan(from, vec2(G.xy)))) {
    uint u = (uint(from.y) * G.x + uint(from.x)) * G.z;
    float n = prev_states[u + 2u * B];
    bool ratio = k >= 2u * B + 1u && k <= 2u * B + 3u;  // the mean distance, P and R are not sums
    s = prev_states[u + k] * (ratio || !(n > scene.guide_learn.z) ? 1.0f : scene.guide_learn.z / n);
  }
  states[i] = s < 1e30f && s >= 0.0f ? s : 0.0f;
#else
  vec4 s = vec4(0.0f);
  if (all(greaterThanEqual(from, vec2(0.0f))) && all(lessThan(from, vec2(G.xy)))) {
    uint u = uint(from.y) * G.x + uint(from.x);
    s = guide_shift(prev_states[u * G.z + k], m.z);
  }
  // A state made unusable by the shift (or never finite) is dropped rather than carried.
  if (!(s.x >= 0.0f && s.x < 1e30f && abs(s.z) < 1e30f && s.w >= 0.0f && s.w < 1e30f)) s = vec4(0.0f);
  states[i] = s;
#endif
}
