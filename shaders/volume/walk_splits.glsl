// Learned walk splits (HAZE_WALK_SPLITS_AUTO), for trace.comp: each dispatch's K comes from the statistics
// of earlier dispatches only, so every sample's estimate stays unbiased whatever K it gets.
#ifndef HAZE_WALK_SPLITS_GLSL
#define HAZE_WALK_SPLITS_GLSL
#include "volume/walk_splits_layout.glsl"

layout(std430, binding = BINDING_split_stats) buffer SplitStats {
  float split_stats[];  // totals, then this dispatch's learning (walk_splits_layout.glsl)
};
// Per pixel: the sum and count of its samples (radiance, channel sums) before the last one, then the last and
// its K (0: none yet). The mean that weighs a pixel comes from samples independent of those it weighs.
layout(std430, binding = BINDING_split_last) buffer SplitLast {
  vec4 split_last[];
};

float channel_sum(vec3 L) {
  return L.x + L.y + L.z;
}

// The walks from one split vertex: the channel sum of the radiance when the current walk started, and the
// sum and sum of squares of the finished walks' contributions at full throughput.
struct SplitWalks {
  float mark, sum, sq;
};
SplitWalks split_walks_start(vec3 L) {
  return SplitWalks(channel_sum(L), 0.0f, 0.0f);
}
// A walk of the K ended with the radiance at L.
void split_walk_ended(INOUT(SplitWalks) w, vec3 L, uint K) {
  float c = (channel_sum(L) - w.mark) * float(K);
  w.sum += c;
  w.sq += c * c;
  w.mark = channel_sum(L);
}
// The K walks' sample variance (0 for one walk).
float split_walks_variance(SplitWalks w, uint K) {
  return K > 1u ? max((w.sq - w.sum * w.sum / float(K)) / float(K - 1u), 0.0f) : 0.0f;
}

// The dispatch's K (the same for every pixel: lanes that split differently would wait for each other): K*
// rounded up with probability equal to its fraction; 2 until the totals hold variances. While learning, a
// dispatch that would take 1 takes 2 with probability 1/2: one walk measures no walk variance, so a rare
// large sample that took K* below 1 early would otherwise end the learning there.
uint walk_splits_choose(uint index, uint seed, bool learning) {
  float k = walk_splits_k(split_stats[SPLIT_WV_WALK], split_stats[SPLIT_WV_BETWEEN], split_stats[SPLIT_N_VAR],
                          split_stats[SPLIT_COST_CAMERA], split_stats[SPLIT_COST_WALK]);
  if (k == 0.0f) return 2u;
  uint rng = rng_init(seed ^ 0x85ebca6bu, 0u, index);
  uint K = min(uint(k + rng_next(rng)), SPLIT_MAX);
  return learning && K < 2u && rng_next(rng) < 0.5f ? 2u : K;
}

void split_learn_add(uint i, float x) {
#if HAZE_SPLIT_SUBGROUP
  x = subgroupAdd(x);
  if (!subgroupElect()) return;
#endif
#if HAZE_SPLIT_ATOMIC_FLOAT
  atomicAdd(split_stats[SPLIT_LEARN + i], x);
#else
  split_stats[SPLIT_LEARN + i] += x;  // concurrent additions may be lost: a noisier K, still unbiased
#endif
}

// After the sample: Y its radiance (channel sum), S the sum over its passes of its walks' sample variance
// (V_w's estimate; K >= 2 only), cost_camera and cost_walk its work outside the walks and per unit of K.
// V_b's estimate is half the squared difference from the pixel's last sample less the walks' share of both
// samples' variances. Both are weighed by the pixel's mean before the last sample: a mean that included
// them would shrink the rare large samples that make up most of a dense medium's variance.
void walk_splits_learn(uint pixel, uint K, float Y, float S, float cost_camera, float cost_walk) {
  vec4 p = split_last[pixel];
  split_last[pixel] = p.w > 0.0f ? vec4(p.x + p.z, p.y + 1.0f, Y, float(K)) : vec4(0.0f, 0.0f, Y, float(K));
  split_learn_add(SPLIT_COST_CAMERA, cost_camera);
  split_learn_add(SPLIT_COST_WALK, cost_walk);
  split_learn_add(SPLIT_N, 1.0f);
  if (K < 2u || p.y == 0.0f) return;
  float m = p.x / p.y;
  float w = 1.0f / (m * m + SPLIT_EPS2);
  float dY = Y - p.z;
  float V_b = 0.5f * dY * dY - 0.5f * S * (1.0f / float(K) + 1.0f / p.w);
  // A sample too large for float sums teaches nothing (its estimate stays in the image): one inf would
  // leave the learned K at 1 for the rest of the run.
  if (!(w * S < 1e30f) || !(abs(w * V_b) < 1e30f)) return;
  split_learn_add(SPLIT_WV_WALK, w * S);
  split_learn_add(SPLIT_WV_BETWEEN, w * V_b);
  split_learn_add(SPLIT_N_VAR, 1.0f);
}

#endif
