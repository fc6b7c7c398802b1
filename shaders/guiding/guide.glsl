// Distance-guiding states and the Gaussian mixture they define (docs/guiding.md, after Alber, Hanika
// and Dachsbacher 2025). Pure functions: the trace pass, the temporal reuse pass and the CPU tests share
// them.
//
// A state is a vec4 {W, N, m1, m2}: running means of a sample's contribution L, of L t and of L t^2 over the
// samples it has seen (N of them, capped). m1 / W is then the contribution-weighted mean distance along the
// ray, and the state stands for a Gaussian there.
#ifndef HAZE_GUIDE_GLSL
#define HAZE_GUIDE_GLSL

#include "common/compat.glsl"
#include "common/sampling.glsl"

const uint GUIDE_MAX_CANDIDATES = 8u;  // guiding/params.hpp kMaxGuideCandidates
// Majorant optical depth beyond which a camera ray is not guided (transmittance below 1e-13).
const float GUIDE_MAX_TAU = 30.0f;

HAZE_INLINE float guide_mean(vec4 s) {
  return s.x > 0.0f ? s.z / s.x : 0.0f;
}

// prm = GpuScene::guide (x P, y min width, z prior width, w prior count; widths relative to t_s). The
// sample variance is pulled towards the prior's width while N is small, and never falls below min width.
HAZE_INLINE float guide_sigma(vec4 s, float t_s, vec4 prm) {
  float mu = guide_mean(s);
  float var = s.x > 0.0f ? max(s.w / s.x - mu * mu, 0.0f) : 0.0f;
  float prior = prm.z * t_s;
  var = (s.y * var + prm.w * prior * prior) / max(s.y + prm.w, 1e-6f);
  return max(sqrt(var), prm.y * t_s);
}

// A candidate's weight: its W, or 0 if it is empty, not finite, or its mean lies outside [0, t_s].
HAZE_INLINE float guide_weight(vec4 s, float t_s) {
  float mu = guide_mean(s);
  bool usable = s.x > 0.0f && s.x < 1e30f && mu >= 0.0f && mu <= t_s && s.w >= 0.0f && s.w < 1e30f;
  return usable ? s.x : 0.0f;
}

// Learning from one sample with contribution L at distance t.
HAZE_INLINE vec4 guide_update(vec4 s, float L, float t, float max_count, float min_alpha) {
  float n = min(s.y + 1.0f, max_count);
  float a = max(1.0f / n, min_alpha);
  return vec4(mix(s.x, L, a), n, mix(s.z, L * t, a), mix(s.w, L * t * t, a));
}

// The same state seen from a camera whose distance to the guided region changed by delta along the ray:
// every t becomes t + delta, so m1 += delta W and m2 += delta (2 m1 + delta W).
HAZE_INLINE vec4 guide_shift(vec4 s, float delta) {
  return vec4(s.x, s.y, s.z + delta * s.x, s.w + delta * (2.0f * s.z + delta * s.x));
}

// q_guide for one distance sample: the candidates' Gaussians truncated to [0, t_s], weighted by W.
struct GuideMixture {
  TruncatedGaussian g[GUIDE_MAX_CANDIDATES];
  float w[GUIDE_MAX_CANDIDATES];
  uint count;
  float total;  // sum of w; 0: no usable candidate, the guide cannot sample
};

HAZE_INLINE GuideMixture guide_mixture_empty() {
  GuideMixture m;
  for (uint c = 0u; c < GUIDE_MAX_CANDIDATES; ++c) {
    m.g[c] = truncated_gaussian(0.0f, 0.0f, 0.0f, 0.0f);
    m.w[c] = 0.0f;
  }
  m.count = 0u;
  m.total = 0.0f;
  return m;
}

HAZE_INLINE void guide_mixture_add(INOUT(GuideMixture) m, vec4 s, float t_s, vec4 prm) {
  if (m.count >= GUIDE_MAX_CANDIDATES) return;
  float w = guide_weight(s, t_s);
  m.w[m.count] = w;
  m.g[m.count] = truncated_gaussian(guide_mean(s), guide_sigma(s, t_s, prm), 0.0f, t_s);
  m.total += w;
  m.count += 1u;
}

// The candidate chosen with probability w / total (u in [0, 1)); the last usable one on rounding.
HAZE_INLINE uint guide_mixture_pick(GuideMixture m, float u) {
  float x = u * m.total;
  uint pick = 0u;
  for (uint c = 0u; c < m.count; ++c) {
    if (m.w[c] > 0.0f) {
      pick = c;
      if (x < m.w[c]) break;
      x -= m.w[c];
    }
  }
  return pick;
}

HAZE_INLINE float guide_mixture_pdf(GuideMixture m, float t) {
  if (!(m.total > 0.0f)) return 0.0f;
  float p = 0.0f;
  for (uint c = 0u; c < m.count; ++c)
    if (m.w[c] > 0.0f) p += m.w[c] * truncated_gaussian_pdf(m.g[c], t);
  return p / m.total;
}

// ---- The histogram model (guiding.model "histogram") ----
// One histogram per grid vertex over distances [0, R] in B equal bins (R: the farthest exit from the bounded
// media along the vertex's rays, trace.comp guide_vertex_range, else the longest guided segment its first
// dispatch saw): bin b holds the sum of the contributions L of the samples that fell in it (its
// expectation is the ray integral over the bin), so it has as many lobes as the rays have sheets. In
// distance, not relative to each ray's segment: neighbouring rays see a sheet at nearly the same distance
// even where their segments end far apart. On a ray it is truncated to [0, min(t_g, R)] and renormalised,
// sampled and evaluated piecewise constant: q_hist(t) = F'_b / F'(t_end) B / R, F' the floored bins. A
// vertex's data (floats):
//   [0, B)    F_b, the folded sums;  [B, 2B) running sums of F_b + GUIDE_FLOOR total / B (the sampler's CDF)
//   2B n (samples),  2B+1 mean distance of the contributions,  2B+2 the vertex's P,  2B+3 R (0: not yet)
//   2B+4 + i  M_i = sum of L^2 q / q_{P_i}: the second moment the estimator would have at P_i
// Its learning buffer: [0, B) sums of L, B n, B+1 + i the M_i, B+1+5 R while it is 0 (the bounds' or the
// longest t_g seen),
// added by the trace pass and folded into the above after each dispatch (guide_hist_fold.comp), so that a
// dispatch samples a histogram nobody writes.
const uint GUIDE_P_CHOICES = 5u;  // guiding/params.hpp kGuideProbabilityChoices
// The sampler's floor per bin, as a share of the histogram's total over B (guide_hist_fold.comp): on the
// bench's beam with multiple scattering relMSE x spp 0.041 without it, 0.021 / 0.019 / 0.017 at 0.25 / 0.5 /
// 1; with the neighbour learning at spacing 10, beam / sheets 0.0156 / 0.235 at 0.5, 0.0147 / 0.245 at 0.75,
// 0.0145 / 0.257 at 1 (docs/guiding.md).
const float GUIDE_FLOOR = 0.75f;

HAZE_INLINE float guide_p_choice(uint i) {
  return i == 0u ? 0.0f : i == 1u ? 0.25f : i == 2u ? 0.5f : i == 3u ? 0.75f : 0.9f;
}
HAZE_INLINE uint guide_hist_stride(uint B) {
  return 2u * B + 4u + GUIDE_P_CHOICES;
}
HAZE_INLINE uint guide_learn_stride(uint B) {
  return B + 2u + GUIDE_P_CHOICES;
}
// The bin of distance t on [0, R] (B beyond: no bin).
HAZE_INLINE uint guide_hist_bin(float t, float R, uint B) {
  if (!(t >= 0.0f && t <= R && R > 0.0f)) return B;
  return min(uint(t * (float(B) / R)), B - 1u);
}
// q_hist at a distance in a bin of mass F_b, the histogram's mass on the ray being total.
HAZE_INLINE float guide_hist_pdf(float F_b, float total, float R, uint B) {
  return total > 0.0f && R > 0.0f ? F_b / total * (float(B) / R) : 0.0f;
}
// The factor q / q_{P_i} that turns a sample's squared estimate into one of the second moment at P_i:
// E_q[L^2 q / q_Pi] = integral of f^2 / q_Pi (q_rest: the mixture without the guide, q_g: the guide's pdf).
HAZE_INLINE float guide_moment_factor(float q, float q_rest, float q_g, float P_i) {
  float q_i = (1.0f - P_i) * q_rest + P_i * q_g;
  return q_i > 0.0f ? q / q_i : 0.0f;
}

#endif
