#version 460
// After each trace dispatch (guiding.model "histogram", docs/guiding.md): each grid vertex adds what the
// dispatch learned to its histogram, rebuilds the running sums the sampler searches, its contribution's
// mean distance, and chooses its P: the P_i whose estimated second moment M_i is least (choose_probability),
// else the scene's P (also while no M_i has been measured); 0 until the histogram has seen B samples. The M_i
// forget (GUIDE_M_KEEP per dispatch): they were measured against the histograms of their time, and the early
// ones are the noisiest. The first fold fixes the histogram's range R.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;
#include "common/compat.glsl"
#include "common/dispatch.glsl"
#include "guiding/guide.glsl"
#include "volume/gpu_scene.glsl"

layout(std430, binding = BINDING_hist) buffer Hist {
  float hist[];
};
layout(std430, binding = BINDING_learn) buffer Learn {
  float learn[];
};

const float GUIDE_M_KEEP = 0.75f;

void main() {
  const uint B = HAZE_GUIDE_BINS;
  uint v = invocation_index();
  if (v >= scene.guide_grid.x * scene.guide_grid.y) return;
  uint h = v * scene.guide_grid.z, l = v * guide_learn_stride(B);
  float R = hist[h + 2u * B + 3u];
  if (R == 0.0f) R = learn[l + B + 1u + GUIDE_P_CHOICES];
  learn[l + B + 1u + GUIDE_P_CHOICES] = 0.0f;
  hist[h + 2u * B + 3u] = R;
  float total = 0.0f, mean_u = 0.0f;
  for (uint b = 0u; b < B; ++b) {
    float F = hist[h + b] + learn[l + b];
    learn[l + b] = 0.0f;
    hist[h + b] = F;
    total += F;
    mean_u += F * ((float(b) + 0.5f) / float(B));
  }
  // The sampler's running sums add a floor of GUIDE_FLOOR / B of the total to every bin: bins whose samples
  // have not yet found the light they hold (noisy multiple scattering) keep some density.
  float floor_b = GUIDE_FLOOR * total / float(B), c = 0.0f;
  for (uint b = 0u; b < B; ++b) {
    c += hist[h + b] + floor_b;
    hist[h + B + b] = c;
  }
  float n = hist[h + 2u * B] + learn[l + B];
  learn[l + B] = 0.0f;
  hist[h + 2u * B] = n;
  hist[h + 2u * B + 1u] = total > 0.0f ? mean_u / total * R : 0.0f;
  float P = total > 0.0f ? scene.guide.x : 0.0f;
  float M_best = 0.0f;
  for (uint i = 0u; i < GUIDE_P_CHOICES; ++i) {
    float M = GUIDE_M_KEEP * hist[h + 2u * B + 4u + i] + learn[l + B + 1u + i];
    learn[l + B + 1u + i] = 0.0f;
    hist[h + 2u * B + 4u + i] = M;
    if (scene.guide.y > 0.5f && (i == 0u || M < M_best)) {
      M_best = M;
      P = guide_p_choice(i);
    }
  }
  // No second moments yet (the histogram was empty while its samples were drawn): the scene's P for one
  // dispatch, whose samples measure them.
  if (scene.guide.y > 0.5f && !(M_best > 0.0f)) P = scene.guide.x;
  if (scene.guide.y > 0.5f && !(total > 0.0f && n >= float(B) && M_best < 1e30f)) P = 0.0f;
  hist[h + 2u * B + 2u] = P;
}
