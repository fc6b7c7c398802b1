// Learned walk splits (render.walk_splits 0, HAZE_WALK_SPLITS_AUTO), shared with the host: the statistics'
// layout and the choice of K they imply (docs/rendering.md, "Split walks").
//
// A camera sample with K walks from its first medium vertex has variance V_b + V_w / K and cost
// C_c + K C_w: V_w is the variance of one walk given the vertex, V_b the rest (the camera ray, the vertex's
// NEE, where the vertex lies), C_c the cost outside the walks. Summed over the image (each pixel's variance
// relative to its mean, as relMSE weighs it), the product of total variance and total cost is least at
// K* = sqrt(V_w C_c / (V_b C_w)).
#ifndef HAZE_WALK_SPLITS_LAYOUT_GLSL
#define HAZE_WALK_SPLITS_LAYOUT_GLSL
#include "common/compat.glsl"

// Two slots of SPLIT_SLOT floats (binding "split_stats"): the totals of earlier dispatches, which the trace
// reads, then what the current dispatch learns, which a fold pass adds to the totals after it. Per slot: the
// sums over camera samples of K >= 2 dispatches of w V_w-hat and w V_b-hat (w = 1 / (m^2 + SPLIT_EPS2), m
// the pixel's mean) and their count; over all samples, the cost outside the walks (C_c) and per unit of K
// (C_w) in lookups, a tracking query counting SPLIT_QUERY_WORK beyond its own, and their count.
const uint SPLIT_WV_WALK = 0u, SPLIT_WV_BETWEEN = 1u, SPLIT_N_VAR = 2u;
const uint SPLIT_COST_CAMERA = 3u, SPLIT_COST_WALK = 4u, SPLIT_N = 5u;
const uint SPLIT_SLOT = 8u, SPLIT_TOTALS = 0u, SPLIT_LEARN = SPLIT_SLOT;
const uint SPLIT_MAX = 16u;  // the largest learned K (render.walk_splits' range)
// Dispatches that learn: the SPLIT_EXPLORE first, then enough for SPLIT_LEARN_SAMPLES more samples.
// Variances need a pixel's two earlier samples and a current one with K >= 2: these take two walks (one in
// the first two cost a thin medium's scenes a little less and the dense clouds more, docs/benchmarks.md).
// Afterwards K* stays, and neither the trace nor the fold pass learns.
const uint SPLIT_EXPLORE = 3u;
const uint SPLIT_LEARN_SAMPLES = 65536u;
// relMSE's weight (eval/metrics.hpp: 1 / (r^2 + 0.01) per channel) on the channel sums of a grey pixel.
const float SPLIT_EPS2 = 0.09f;
// The cost of a tracking query beyond its density lookups (the state machine's step, BVH traversals, light
// sampling), in lookups: with 1 the walks' share of a dispatch's time came out as measured on lavapipe in
// the room demo (C_w / C_c 0.425 against 0.42; lookups alone gave 0.13, and K 5.4 where 3 is best).
const uint SPLIT_QUERY_WORK = 1u;

HAZE_INLINE bool walk_splits_learning(uint index, uint pixels) {
  return index < SPLIT_EXPLORE + (SPLIT_LEARN_SAMPLES + pixels - 1u) / max(pixels, 1u);
}

// K* from the totals, in [1, SPLIT_MAX]; 0 while they hold no variances yet.
HAZE_INLINE float walk_splits_k(float wv_walk, float wv_between, float n_var, float cost_camera,
                                float cost_walk) {
  if (!(n_var > 0.0f)) return 0.0f;
  if (!(cost_walk > 0.0f) || !(wv_walk > 0.0f)) return 1.0f;
  if (!(wv_between > 0.0f)) return float(SPLIT_MAX);
  return clamp(sqrt(wv_walk * cost_camera / (wv_between * cost_walk)), 1.0f, float(SPLIT_MAX));
}

#endif
