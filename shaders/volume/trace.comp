#version 460
// One camera sample per pixel per dispatch: the surface term T(0,t_s) L_bg and the volume term
// (N distance samples on [0, t_s] from the mixture q(t), NEE with ratio-tracked shadow rays, and a
// delta-tracked random walk for multiple scattering). Results are added to per-pixel sums and squares.
// With HAZE_VOLPATH (render.estimator "volpath") the same kernel is pbrt-v4's VolPathIntegrator for grey
// media instead, the baseline of haze bench's efficiency figures: the camera ray is the first delta-tracked
// walk ray, real collisions absorb or scatter, NEE at every vertex, plain ratio tracking with pbrt's
// roulette.
//
// With HAZE_MIS (render.mis "power", walks of more than one event, and an environment or emissive triangles)
// both estimators weigh the two strategies that reach the environment and emissive triangles, light
// sampling at NEE and the walk's phase/BSDF sampling, by the power heuristic on their per-vertex densities;
// without it NEE alone carries these lights and walk rays that escape or hit an emitter add nothing.
//
// The estimator runs as a small state machine whose loop issues one tracking query per iteration, so the
// tracker (and its single density-lookup call site) is inlined once.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#if HAZE_GUIDE_ATOMIC_FLOAT || HAZE_SPLIT_ATOMIC_FLOAT
#extension GL_EXT_shader_atomic_float : require
#endif
#if HAZE_SPLIT_SUBGROUP
#extension GL_KHR_shader_subgroup_arithmetic : require
#endif

layout(local_size_x = 8, local_size_y = 8) in;

#include "common/camera.glsl"
#include "common/color.glsl"
#include "common/compat.glsl"
#include "common/rng.glsl"
#include "common/sampling.glsl"
#include "volume/gpu_scene.glsl"

// The bindings come from the kernel's declaration (render/renderer.cpp): the scene block, the accumulation
// layers, and whatever the scene's parts declare (lights, media, surfaces, guiding).
PIXEL_LAYER(acc_l);
PIXEL_LAYER(acc_l2);
PIXEL_LAYER(acc_vol);
PIXEL_LAYER(acc_vol2);
PIXEL_LAYER(acc_surf);
PIXEL_LAYER(acc_surf2);
PIXEL_LAYER(acc_demod);
PIXEL_LAYER(acc_demod2);
#ifdef BINDING_acc_emit
PIXEL_LAYER(acc_emit);  // scenes with emissive surfaces only
#endif
PIXEL_LAYER(acc_vp);
layout(std430, binding = BINDING_counters) buffer Counters {
  uint counters[];  // COUNT_*, 64-bit each: low, high
};

// Adds v to 64-bit counter c (carry into the high word when the low one wraps).
void counter_add(uint c, uint v) {
  if (v == 0u) return;
  uint old = atomicAdd(counters[2u * c], v);
  if (old + v < old) atomicAdd(counters[2u * c + 1u], 1u);
}

#include "lights/lights.glsl"
#include "volume/medium.glsl"
#if HAZE_WALK_SPLITS_AUTO
#include "volume/walk_splits.glsl"
#endif
#if HAZE_SURFACES
#include "surfaces/material.glsl"
#endif
#if HAZE_GUIDING
#include "guiding/guide.glsl"
#if HAZE_GUIDE_HIST
// A histogram per grid vertex (guide.glsl layout), read only here; this dispatch's learning goes to
// guide_learn, which the fold pass adds after it.
layout(std430, binding = BINDING_guide_hist) readonly buffer GuideHist {
  float guide_hist[];
};
layout(std430, binding = BINDING_guide_learn) buffer GuideLearn {
  float guide_learn[];
};
const uint GUIDE_BINS = HAZE_GUIDE_BINS;
#else
// K states per grid vertex, read and written by every sample (a Markov chain of states, not a histogram).
layout(std430, binding = BINDING_guide_states) buffer GuideStates {
  vec4 guide_states[];
};
#endif
#endif

layout(push_constant) uniform Push {
  uint sample_index;
  uint split_index;  // learned walk splits: dispatches since their statistics were emptied
}
pc;

const int ST_SURFACE = 0;  // ratio tracking T(0, t_s) for the surface term
const int ST_CAMERA = 1;   // ratio tracking T(0, t_j) to a sampled distance, with the medium at t_j
const int ST_SHADOW = 2;   // ratio tracking towards a light
const int ST_WALK = 3;     // delta tracking to the next scattering vertex
const int ST_START = 4;    // nothing tracked yet: the first volume sample starts

// Russian roulette of the walk on the path throughput relative to its value at the first vertex (so that
// it does not depend on the camera sample's 1/q or N): below PATH_RR it survives with probability
// (relative throughput) / PATH_RR.
const float PATH_RR = 0.25f;
const float TAU_DELTA = 0.1f;
#if HAZE_VOLPATH
// pbrt-v4's roulette of ratio-tracked transmittance (VolPathIntegrator::SampleLd).
const float RATIO_RR = 0.05f, RATIO_RR_SURVIVE = 0.25f;
#endif

#if HAZE_GUIDING
// A grid vertex next to grid position g (stochastic bilinear choice).
uint guide_vertex(vec2 g, inout uint rng) {
  vec2 f = g - floor(g);
  ivec2 v = ivec2(floor(g)) + ivec2(rng_next(rng) < f.x ? 1 : 0, rng_next(rng) < f.y ? 1 : 0);
  v = clamp(v, ivec2(0), ivec2(scene.guide_grid.xy) - 1);
  return uint(v.y) * scene.guide_grid.x + uint(v.x);
}
#if HAZE_GUIDE_HIST
// Running sum of bins 0..b of the histogram at float offset h (b < 0: 0).
float guide_cdf(uint h, int b) {
  return b < 0 ? 0.0f : guide_hist[h + GUIDE_BINS + uint(b)];
}
// The histogram at h on one ray: its range R and its part [0, t_end] on the ray, with the mass there.
struct GuideRay {
  uint h;
  float R, t_end, total;
};
GuideRay guide_ray(uint h, float R, float t_g) {
  GuideRay g;
  g.h = h;
  g.R = R;
  g.t_end = min(t_g, g.R);
  g.total = 0.0f;
  uint b = guide_hist_bin(g.t_end, g.R, GUIDE_BINS);
  if (b < GUIDE_BINS) {
    float c0 = guide_cdf(h, int(b) - 1);
    g.total =
        c0 + (guide_cdf(h, int(b)) - c0) * clamp(g.t_end * (float(GUIDE_BINS) / g.R) - float(b), 0.0f, 1.0f);
  }
  return g;
}
// q_hist(t) on the ray; a bin's mass is a difference of running sums, as the sampler sees it.
float guide_hist_pdf_at(GuideRay g, float t) {
  uint b = guide_hist_bin(t, g.R, GUIDE_BINS);
  if (b >= GUIDE_BINS || t > g.t_end) return 0.0f;
  return guide_hist_pdf(guide_cdf(g.h, int(b)) - guide_cdf(g.h, int(b) - 1), g.total, g.R, GUIDE_BINS);
}
// A distance from the histogram on the ray (total > 0): the first bin whose running sum exceeds u total,
// then uniform within it (u reused); the last bin is cut at t_end.
float guide_hist_sample(GuideRay g, float u) {
  uint h = g.h;
  float x = u * g.total;
  int lo = 0, hi = int(guide_hist_bin(g.t_end, g.R, GUIDE_BINS));
  while (lo < hi) {
    int mid = (lo + hi) / 2;
    if (guide_cdf(h, mid) > x)
      hi = mid;
    else
      lo = mid + 1;
  }
  float c0 = guide_cdf(h, lo - 1), c1 = guide_cdf(h, lo);
  float f = c1 > c0 ? clamp((x - c0) / (c1 - c0), 0.0f, 1.0f) : 0.5f;
  float t = min(g.R * ((float(lo) + f) / float(GUIDE_BINS)), g.t_end);
  // Rounding must not carry t into a neighbouring bin, whose pdf would then be used.
  if (guide_hist_bin(t, g.R, GUIDE_BINS) != uint(lo))
    t = min(g.R * ((float(lo) + 0.5f) / float(GUIDE_BINS)), g.t_end);
  return t;
}
// The range R of the histogram of vertex gv where the media are bounded: the farthest exit from them along
// 3 x 3 rays through the vertex's footprint (the pixels nearest to it), known before its first sample, so
// that the first dispatch already bins; 0 where they are unbounded (R is then the longest t_g seen).
float guide_vertex_range(uvec2 gv) {
  vec2 size = vec2(scene.size.xy);
  vec2 lo = clamp((vec2(gv) - 0.5f) * scene.guide_learn.x, vec2(0.0f), size);
  vec2 hi = clamp((vec2(gv) + 0.5f) * scene.guide_learn.x, vec2(0.0f), size);
  float R = 0.0f;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      vec3 d = camera_direction(scene.cam_right.xyz, scene.cam_up.xyz, scene.cam_forward.xyz,
                                mix(lo, hi, vec2(i, j) * 0.5f), size);
      R = max(R, media_exit(scene.cam_position.xyz, d));
    }
  return R < 1e18f ? R : 0.0f;
}
void guide_learn_add(uint i, float x) {
#if HAZE_GUIDE_ATOMIC_FLOAT
  atomicAdd(guide_learn[i], x);
#else
  guide_learn[i] += x;  // concurrent additions may be lost: fewer samples, still a valid histogram
#endif
}
#else
// A random state slot at a grid vertex next to grid position g.
uint guide_slot(vec2 g, inout uint rng) {
  uint K = scene.guide_grid.z;
  return guide_vertex(g, rng) * K + min(uint(rng_next(rng) * float(K)), K - 1u);
}
#endif
#endif

// x², capped at SQUARE_MAX (an overflow to Inf included); `clamped` tells whether any component was.
vec3 square_capped(vec3 x, inout bool clamped) {
  vec3 s = x * x;
  clamped = clamped || any(greaterThan(s, vec3(SQUARE_MAX)));
  return min(s, vec3(SQUARE_MAX));
}

#if HAZE_LOCAL
// Equi-angular sampling towards local light k on [0, t_s]; a spot's restricted to the part of the ray inside
// its cone (it lights nothing elsewhere), when q_base covers the rest (clip): the sample and its pdf use the
// same segment. `empty`: the ray misses the cone, the light yields no sample and its pdf is 0.
struct LightSegment {
  EquiAngular e;
  float t0, t1;
  bool empty;
};
LightSegment light_segment(vec3 o, vec3 d, uint k, float t_s, bool clip) {
  LightSegment s;
  GpuLight l = lights[k];
  vec2 ab = clip ? cone_clip(o, d, l.position.xyz, l.direction.xyz, l.params.x, 0.0f, t_s) : vec2(0.0f, t_s);
  s.empty = !(ab.x < ab.y);
  s.t0 = ab.x;
  s.t1 = s.empty ? ab.x : ab.y;
  s.e = equi_angular_setup(o, d, lights[k].position.xyz, s.t0, s.t1);
  return s;
}
float light_segment_pdf(LightSegment s, float t) {
  return s.empty || t < s.t0 || t > s.t1 ? 0.0f : equi_angular_pdf(s.e, t);
}
#endif

// Offset of ray origins off a surface, relative to the scene's scale at that point.
float surface_epsilon(vec3 x) {
  return 1e-4f * max(1.0f, max(abs(x.x), max(abs(x.y), abs(x.z))));
}

// Solid-angle density of the walk's direction wi at a medium vertex reached along d: the phase function,
// or with HAZE_SUN_WALK its mixture with the sun lobe (probability sun_walk.x, HG g sun_walk.y).
float walk_phase_pdf(vec3 wi, vec3 d, float g) {
#if HAZE_SUN_WALK
  return mix(hg_phase(dot(wi, d), g), hg_phase(dot(wi, scene.sun_direction.xyz), scene.sun_walk.y),
             scene.sun_walk.x);
#else
  return hg_phase(dot(wi, d), g);
#endif
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  uint W = scene.size.x, H = scene.size.y;
  if (pix.x >= W || pix.y >= H) return;
  uint pixel = pix.y * W + pix.x;
  uint rng = rng_init(scene.counts.w, pixel, pc.sample_index);
#if HAZE_HETERO
  media_begin_sample();
#endif

  vec2 jitter = scene.settings.z > 0.5f ? vec2(rng_next(rng), rng_next(rng)) : vec2(0.5f);
  vec3 cam_o = scene.cam_position.xyz;
  vec3 cam_d = camera_direction(scene.cam_right.xyz, scene.cam_up.xyz, scene.cam_forward.xyz,
                                vec2(pix) + jitter, vec2(W, H));
  float t_s = media_exit(cam_o, cam_d);
  const float t_media = t_s;  // where the ray leaves the last medium
  bool cam_hit = false;
#if HAZE_SURFACES
  BvhHit cam_h = bvh_closest_hit(cam_o, cam_d, 0.0f, T_INF);
  if (cam_h.triangle != BVH_NONE) {
    cam_hit = true;
    t_s = cam_h.t;
  }
#endif
  uint N = scene.size.z;
  uint max_depth = scene.size.w;
#if HAZE_VOLPATH
  float rr_T = RATIO_RR, rr_T_survive = RATIO_RR_SURVIVE;
#else
  float rr_T = scene.settings.y, rr_T_survive = 0.25f;
#endif

  vec3 L_surf = vec3(0.0f), L_vol = vec3(0.0f);
  vec3 albedo0 = vec3(1.0f);  // albedo of the camera's surface hit, for demodulation
  vec3 E_surf = vec3(0.0f);   // the camera hit's emission (in L_surf, kept out of the demodulated term)
  float T_surf = 1.0f;
  // What this sample's tracking did and what it cut, added to the frame's counters once at the end.
  uint n_lookups = 0u, n_real = 0u, n_null = 0u, n_distance = 0u, n_guided = 0u;
  bool step_capped = false, violated = false;
#if HAZE_WALK_SPLITS_AUTO
  bool split_learning = walk_splits_learning(pc.split_index, W * H);
  uint walk_K = walk_splits_choose(pc.sample_index, scene.counts.w, split_learning);
  // What the dispatch learns from: the work (SPLIT_QUERY_WORK per tracking query plus its lookups) in all
  // and in the walks, and the sum over passes of the walks' sample variance.
  uint n_work = 0u, split_work = 0u;
  float split_S = 0.0f;
#elif HAZE_WALK_SPLITS
  const uint walk_K = uint(HAZE_WALK_SPLITS);
#endif

#if !HAZE_VOLPATH
  // Distance sampling on the camera ray: q(t) = (1 - P) [p_base q_base(t) + p_ea q_ea(t)] + P q_guide(t),
  // or delta tracking where no equi-angular share needs the sample's pdf and the ray meets a heterogeneous
  // majorant optical depth of TAU_DELTA: its real collision has weight 1, where a forced sample's weight
  // T sigma_t / q grows with the majorant's looseness. Such rays are not guided either (P = 0): on the
  // bench's VDB shaft a delta-tracked sample had half the error of a guided one, at a fifth of the time.
  // The majorant walk stops at TAU_DELTA (no pass over the rest).
  float p_ea = 0.0f;
#if HAZE_LOCAL
  uint K = scene.counts.z;
  if (K > 0u && t_s > 0.0f) p_ea = scene.settings.x;
#endif
  bool may_delta = p_ea == 0.0f;
  MajWalk cam_walk = maj_walk(cam_o, cam_d, 0.0f, t_s, may_delta ? TAU_DELTA : T_INF);
  bool delta_cam = may_delta && cam_walk.tau >= TAU_DELTA && cam_walk.tau_het >= 0.5f * TAU_DELTA;
  if (may_delta && !delta_cam && cam_walk.tau >= TAU_DELTA)
    cam_walk = maj_walk(cam_o, cam_d, 0.0f, t_s, T_INF);
  float tau_total = cam_walk.tau;  // unused by delta-tracked rays
  float p_base = tau_total > 0.0f ? 1.0f : 0.0f;
#if HAZE_LOCAL
  if (K > 0u && t_s > 0.0f) {
    p_ea = tau_total > 0.0f ? p_ea : 1.0f;
    p_base = 1.0f - p_ea;
  }
#endif
#if HAZE_GUIDING
  // The guide spreads over [0, t_g]: the ray up to t_s and out of the media (a surface behind them must not
  // stretch a histogram's bins), but no further than a majorant optical depth of GUIDE_MAX_TAU (light from
  // beyond is negligible; q_base still covers it).
  float t_g =
      tau_total > GUIDE_MAX_TAU ? maj_walk(cam_o, cam_d, 0.0f, t_s, GUIDE_MAX_TAU).t : min(t_s, t_media);
  vec2 guide_pos = (vec2(pix) + jitter) / scene.guide_learn.x;
#if HAZE_GUIDE_HIST
  // The vertices choose their P (guide.y) or take the scene's: here P_guide only says the guide is on.
  float P_guide =
      t_g > 0.0f && t_g < 1e18f && !delta_cam && (scene.guide.y > 0.5f || scene.guide.x > 0.0f) ? 1.0f : 0.0f;
  // The current sample's vertex's histogram on this ray (total 0: empty).
  GuideRay guide_r = GuideRay(0u, 0.0f, 0.0f, 0.0f);
  // The nearest vertex: a histogram learns from rays that see their sheets at about the same distances (a
  // stochastic bilinear choice doubles the footprint; measured no better, docs/guiding.md). Its range R:
  // stored once its first dispatch is folded; before that, from the media's bounds (or 0: not yet known).
  uvec2 guide_gv = uvec2(clamp(ivec2(round(guide_pos)), ivec2(0), ivec2(scene.guide_grid.xy) - 1));
  uint guide_h = (guide_gv.y * scene.guide_grid.x + guide_gv.x) * scene.guide_grid.z;
  float guide_R = guide_hist[guide_h + 2u * GUIDE_BINS + 3u];
  bool guide_R_new = guide_R == 0.0f;
  if (guide_R_new && P_guide > 0.0f) guide_R = guide_vertex_range(guide_gv);
  float q_rest = 0.0f, q_guide = 0.0f;  // q(t_j) without the guide, and the histogram's pdf at t_j
#else
  float P_guide = t_g > 0.0f && t_g < 1e18f && !delta_cam ? scene.guide.x : 0.0f;
  vec4 guide_chosen = vec4(0.0f);  // the state the current sample learns into
  float guide_mean_w = 0.0f;       // mean candidate weight, the bar for writing a state back
#endif
#endif
  // The first sample's delta track also estimates T(0, t_s) (1 when it reaches t_s): the surface term
  // needs no pass of its own.
  bool surface_from_delta = delta_cam;
  // A ray that meets no heterogeneous majorant crosses the haze alone: its transmittances are closed forms
  // and the medium at a distance sample is the haze, so its camera queries need no tracking.
  bool haze_only = cam_walk.tau_het == 0.0f;
#endif
  float t_j = 0.0f;  // distance of the current volume sample (volpath: of the camera ray's first vertex)
  vec3 L_vol_start = vec3(0.0f);
  // Virtual point sums (ACC_VP_*).
  float vp_wt = 0.0f, vp_w = 0.0f, vp_g = 0.0f, vp_gn = 0.0f;

  // Path state.
  int state = ST_SURFACE;
  vec3 q_o = cam_o, q_d = cam_d;
  float q_t0 = 0.0f, q_t1 = t_s;
  int q_mode = TRACK_RATIO;
  bool q_eval = false;
  uint depth = 0u;          // scattering events so far (volume or surface)
  bool to_surface = false;  // the path belongs to the surface term (else to the volume term)
  vec3 x = cam_o;           // current vertex
  vec3 d = cam_d;           // direction the path travelled to reach x
  vec3 beta = vec3(0.0f);
  float beta_start = 0.0f;    // max component of beta at the path's first vertex (the roulette's yardstick)
  vec3 pending = vec3(0.0f);  // NEE contribution waiting for its shadow-ray transmittance
  float q_j = 1.0f;           // q(t_j) of the current distance sample
  float g = 0.0f;             // phase anisotropy at a volume vertex
  bool on_surface = false;    // the vertex is on a surface (normal n, albedo alb) rather than in a medium
  vec3 n = vec3(0.0f, 1.0f, 0.0f), alb = vec3(0.0f);
  vec3 ns = n;  // the shading normal (surfaces/material.glsl); n, the geometric one, offsets rays
#if HAZE_MIS
  float p_walk = 0.0f;  // solid-angle density of the current walk ray's direction (phase or cosine sampling)
#endif
  // Surface the current walk ray reaches if no medium stops it first.
  bool walk_hit = false;
#if HAZE_SURFACES
  BvhHit walk_h;
#endif
#if HAZE_VOLPATH
  // One path per camera sample: the camera ray is the first walk ray, with throughput 1.
  uint passes = 1u;
#else
  // Pass 0 is the surface term (T(0, t_s) by ratio tracking, then its NEE and walk); passes 1..N are the
  // volume samples. Each pass is one path: the inner loop runs its tracking queries, one per iteration, and
  // the distance sampling stays outside it.
  uint passes = N + 1u;
#endif
  TrackResult known;  // a query's result in closed form
  known.T = Trans(1.0f);
  known.hit = false;
  known.t = 0.0f;
  known.ms = haze_at(cam_o);
  known.lookups = 0u;
  known.nulls = 0u;
  known.capped = false;
  known.violated = false;
  bool q_known = false;
  float q_rr = rr_T;    // the roulette threshold of the current ratio-tracking query
  float q_tau = -1.0f;  // the query's first majorant optical depth to a tentative collision (< 0: drawn)
  for (uint pass = 0u; pass < passes; ++pass) {
#if HAZE_WALK_SPLITS
    bool split_done = false;  // this pass's first medium vertex has saved its walks
    uint split_left = 0u;     // walks still to start from it
    vec3 split_x = vec3(0.0f), split_d = vec3(0.0f), split_beta = vec3(0.0f);
    float split_g = 0.0f, split_beta_start = 0.0f;
    float split_u = 0.0f;  // the offset of the walks' strata of their first direction
#if HAZE_WALK_SPLITS_AUTO
    uint split_work0 = 0u;  // n_work when the walks started
    SplitWalks split_walks = split_walks_start(L_vol);
#endif
#endif
    to_surface = false;
    d = cam_d;
    q_o = cam_o;
    q_d = cam_d;
    q_t0 = 0.0f;
#if HAZE_VOLPATH
    state = ST_WALK;
    q_t1 = t_s;
    q_mode = TRACK_DELTA;
    q_eval = false;
    beta = vec3(1.0f);
    beta_start = 1.0f;
    T_surf = 0.0f;  // 1 when the camera ray reaches t_s: delta tracking's estimate of T(0, t_s)
    walk_hit = cam_hit;
#if HAZE_SURFACES
    walk_h = cam_h;
#endif
#else
    if (pass == 0u) {
      // With delta-tracked samples the first sample's track estimates T(0, t_s) too.
      if (surface_from_delta) continue;
      state = ST_SURFACE;
      q_t1 = t_s;
      q_mode = TRACK_RATIO;
      q_eval = false;
      if (haze_only) {
        known.T = haze_transmittance(tau_total);
        q_known = true;
        if (!cam_hit) {
          T_surf = trans_mean(known.T);
          L_surf = known.T * background(cam_d);
          continue;
        }
      }
    } else {
      if ((p_base + p_ea) == 0.0f) break;  // no medium along the ray
      n_distance += 1u;
      L_vol_start = L_vol;
      // Draw t_j from the mixture and evaluate q(t_j); or delta-track the ray (weight 1 at its collision).
      float t = 0.0f;
      float u_pick = rng_next(rng);
      float u_t = rng_next(rng);
      float P = 0.0f;
#if HAZE_GUIDE_HIST
      if (P_guide > 0.0f) {
        guide_r = guide_ray(guide_h, guide_R, t_g);
        if (guide_r.total > 0.0f) {
          P = guide_hist[guide_r.h + 2u * GUIDE_BINS + 2u];
          vp_g += guide_hist[guide_r.h + 2u * GUIDE_BINS + 1u];
          vp_gn += 1.0f;
        }
        if (u_pick < P) {
          t = guide_hist_sample(guide_r, u_t);
          u_pick = 2.0f;  // neither base nor equi-angular below
          n_guided += 1u;
        } else {
          u_pick = (u_pick - P) / (1.0f - P);
        }
      }
#elif HAZE_GUIDING
      GuideMixture gm = guide_mixture_empty();
      uint slots[GUIDE_MAX_CANDIDATES];
      if (P_guide > 0.0f) {
        uint C = min(scene.guide_grid.w, GUIDE_MAX_CANDIDATES);
        for (uint c = 0u; c < C; ++c) {
          slots[c] = guide_slot(guide_pos, rng);
          guide_mixture_add(gm, guide_states[slots[c]], t_g, scene.guide);
        }
        // Learning continues from a candidate chosen by weight (any one while none is usable).
        uint chosen = gm.total > 0.0f ? guide_mixture_pick(gm, rng_next(rng))
                                      : min(uint(rng_next(rng) * float(C)), C - 1u);
        guide_chosen = guide_states[slots[chosen]];
        guide_mean_w = gm.total / float(C);
        if (gm.total > 0.0f) {
          P = P_guide;
          vp_g += guide_mean(guide_chosen);
          vp_gn += 1.0f;
        }
        if (u_pick < P) {
          t = truncated_gaussian_sample(gm.g[chosen], u_t);
          u_pick = 2.0f;  // neither base nor equi-angular below
          n_guided += 1u;
        } else {
          u_pick = (u_pick - P) / (1.0f - P);
        }
      }
#endif
      if (delta_cam) {
        q_t1 = t_s;
        q_mode = TRACK_DELTA;
        q_eval = false;
        // The majorant walk met optical depth cam_walk.tau by cam_walk.t: a first tentative collision beyond
        // it (by memorylessness, the rest of the exponential) is tracked from there, without stepping again
        // through the cells before it.
        q_tau = -log_one_minus(rng_next(rng));
        if (q_tau >= cam_walk.tau) {
          q_t0 = cam_walk.t;
          q_tau -= cam_walk.tau;
        }
      } else {
        // The majorant walk to t: q_base samples where it stops, the others walk to the t they drew (one
        // call site, one inlined DDA).
        bool base = u_pick <= 1.5f && u_pick < p_base;
        bool ea_empty = false;
#if HAZE_LOCAL
        // Spots' cones clip their equi-angular segments only where q_base covers the rest of the ray.
        bool cone_clipped = p_base > 0.0f;
#endif
        if (u_pick <= 1.5f && !base) {
#if HAZE_LOCAL
          uint k = min(uint((u_pick - p_base) / p_ea * float(K)), K - 1u);
          LightSegment ls = light_segment(cam_o, cam_d, k, t_s, cone_clipped);
          t = equi_angular_sample(ls.e, u_t);
          ea_empty = ls.empty;
#endif
          t = clamp(t, 0.0f, t_s);
        }
        MajWalk mw = maj_walk(cam_o, cam_d, 0.0f, base ? t_s : t,
                              base ? truncated_exp_sample_tau(tau_total, u_t) : T_INF);
        if (base) t = mw.t;
        float q = p_base > 0.0f ? p_base * mw.sigma * truncated_exp_pdf_tau(mw.tau, tau_total) : 0.0f;
#if HAZE_LOCAL
        for (uint k = 0u; k < K; ++k)
          q += p_ea / float(K) * light_segment_pdf(light_segment(cam_o, cam_d, k, t_s, cone_clipped), t);
#endif
#if HAZE_GUIDE_HIST
        q_rest = q;
        q_guide = guide_r.total > 0.0f ? guide_hist_pdf_at(guide_r, t) : 0.0f;
        q = (1.0f - P) * q + P * q_guide;
#elif HAZE_GUIDING
        q = (1.0f - P) * q + P * guide_mixture_pdf(gm, t);
#endif
        // A sample the mixture cannot produce again contributes nothing (nor does a light's empty segment).
        q_j = q > 0.0f && !ea_empty ? q : T_INF;
        t_j = t;
        x = cam_o + cam_d * t;
        q_t1 = t;
        q_mode = TRACK_RATIO;
        q_eval = true;
        if (haze_only) {
          known.T = haze_transmittance(mw.tau);
          known.ms = haze_at(x);
          q_known = true;
        }
      }
      state = ST_CAMERA;
    }
#endif

    for (;;) {
      // The pass's first query may be known in closed form (haze_only).
      TrackResult r = known;
      if (!q_known) r = track(q_o, q_d, q_t0, q_t1, q_mode, q_eval, q_rr, rr_T_survive, q_tau, rng);
      q_known = false;
      q_rr = rr_T;
      q_tau = -1.0f;
      n_lookups += r.lookups;
#if HAZE_WALK_SPLITS_AUTO
      n_work += SPLIT_QUERY_WORK + r.lookups;
#endif
      n_null += r.nulls;
      if (r.hit) n_real += 1u;
      step_capped = step_capped || r.capped;
      violated = violated || r.violated;
      bool next_sample = false;  // the path is complete
      bool do_nee = false;       // a scattering vertex is ready at x

#if !HAZE_VOLPATH
      if (state == ST_CAMERA && q_mode == TRACK_DELTA && pass == 1u && surface_from_delta) {
        // The first delta track is the surface term's too: reaching t_s is its estimate of T(0, t_s).
        if (r.hit) {
          T_surf = 0.0f;
        } else {
          state = ST_SURFACE;
#if !HAZE_CHROMATIC
          r.T = 1.0f;  // chromatic: r.T is the spectral tracking weight of reaching t_s, T's estimate
#endif
        }
      }
#endif
      if (state == ST_SURFACE) {
        T_surf = trans_mean(r.T);
        if (cam_hit) {
#if HAZE_SURFACES
          GpuInstance inst = instances[cam_h.instance];
          L_surf = r.T * inst.emission.rgb;
#ifdef BINDING_acc_emit
          E_surf = L_surf;  // else the scene has no emissive surface and E_surf stays 0 (folded away)
#endif
          x = cam_o + cam_d * t_s;
          n = dot(cam_h.normal, cam_d) < 0.0f ? cam_h.normal : -cam_h.normal;
          ns = surface_normal(cam_h, n);
          alb = surface_albedo(cam_h);
          albedo0 = alb;
          on_surface = true;
          to_surface = true;
          beta = vec3(r.T);
          beta_start = trans_max(r.T);
          depth = 1u;
          do_nee = max_depth > 0u && trans_max(r.T) > 0.0f;
          next_sample = !do_nee;
#endif
        } else {
          L_surf = r.T * background(cam_d);
          next_sample = true;
        }
      } else if (state == ST_CAMERA) {
        // r.T = T(0,t_j) estimate; the camera-ray contribution is T sigma (...) / q(t_j), averaged over N.
        // A delta-tracked sample has weight 1 at its real collision (T sigma_t is its pdf).
#if HAZE_CHROMATIC
        // Per channel: T_c sigma_t,c / q, sigma_t,c estimated by the chosen component's sigma_t * color.
        Trans w = r.T * r.ms.sigma_t * r.ms.color / (q_j * float(N));
#else
        Trans w = r.T * r.ms.sigma_t / (q_j * float(N));
#endif
        if (q_mode == TRACK_DELTA) {
          // Chromatic: the spectral tracking weight (1 in grey media).
          w = r.hit ? r.T / float(N) : Trans(0.0f);
          t_j = r.t;
          x = cam_o + cam_d * r.t;
        }
        L_vol += w * r.ms.emit;
        if (max_depth > 0u && trans_max(w) > 0.0f) {
          beta = vec3(w) * r.ms.albedo;
          beta_start = trans_max(w);
          g = r.ms.g;
          on_surface = false;
          depth = 1u;
          do_nee = true;
        } else {
          next_sample = true;
        }
      } else if (state == ST_SHADOW) {
        if (to_surface)
          L_surf += pending * r.T;
        else
          L_vol += pending * r.T;
#if HAZE_MULTI || HAZE_SURFACES
        bool walk_on = depth < max_depth;
        if (walk_on) {
          if (on_surface) {
            // Lambertian: cosine sampling makes the weight the albedo. A bounce below the geometric surface
            // reflects nothing (no light leaks through a coarse mesh's terminator).
            d = sample_cosine_hemisphere(ns, vec2(rng_next(rng), rng_next(rng)));
#if HAZE_MIS
            p_walk = max(dot(ns, d), 0.0f) * INV_PI;
#endif
            beta *= alb;
            x += n * surface_epsilon(x);
            walk_on = dot(d, n) > 0.0f;
#if HAZE_VOLPATH
            // pbrt-v4's roulette, at surface vertices after the first: survive with the throughput.
            float m = max(beta.x, max(beta.y, beta.z));
            if (walk_on && depth > 1u && m < 1.0f) {
              if (rng_next(rng) >= m)
                walk_on = false;
              else
                beta /= m;
            }
#endif
          } else {
#if HAZE_WALK_SPLITS
            // The camera sample's first medium vertex starts K walks, each with 1/K of the throughput (and
            // of the roulette's yardstick, so that each walk's roulette is an unsplit one's).
            if (depth == 1u && !split_done) {
              split_done = true;
              split_left = walk_K - 1u;
              split_u = rng_next(rng);
              beta *= 1.0f / float(walk_K);
              beta_start *= 1.0f / float(walk_K);
#if HAZE_WALK_SPLITS_AUTO
              split_work0 = n_work;
              split_walks = split_walks_start(L_vol);
#endif
              split_x = x;
              split_d = d;
              split_beta = beta;
              split_g = g;
              split_beta_start = beta_start;
            }
#endif
            vec3 d_in = d;
#if HAZE_WALK_SPLITS
            // The walks from the split vertex take their first direction's uniform from strata 1/K wide, one
            // each at a shared random offset: each walk's direction keeps its density, and their mean varies
            // less than that of independent ones (towards the sun or away, deeper or out).
            float u_dir = depth == 1u ? fract(split_u + float(walk_K - 1u - split_left) / float(walk_K))
                                      : rng_next(rng);
#else
            float u_dir = rng_next(rng);
#endif
#if HAZE_SUN_WALK
            // A mixture of the phase function and a lobe towards the sun: in dense media the walk reaches
            // the lit side in fewer events. The weight f / pdf stays below 1 / (1 - P). One uniform chooses
            // the lobe and, rescaled, the angle to its axis.
            float P_sun = scene.sun_walk.x;
            bool to_sun = u_dir < P_sun;
            float u_mu = to_sun ? u_dir / P_sun : (u_dir - P_sun) / (1.0f - P_sun);
            d = hg_sample(to_sun ? scene.sun_direction.xyz : d_in, to_sun ? scene.sun_walk.y : g,
                          vec2(min(u_mu, 0.99999994f), rng_next(rng)));
            float f = hg_phase(dot(d, d_in), g);
            float pdf = walk_phase_pdf(d, d_in, g);
            beta *= f / pdf;
#if HAZE_MIS
            p_walk = pdf;
#endif
#else
            d = hg_sample(d_in, g, vec2(u_dir, rng_next(rng)));
#if HAZE_MIS
            p_walk = hg_phase(dot(d, d_in), g);
#endif
#endif
          }
        }
        if (walk_on) {
          q_o = x;
          q_d = d;
          q_t0 = 0.0f;
          q_t1 = media_exit(x, d);
          walk_hit = false;
#if HAZE_SURFACES
          walk_h = bvh_closest_hit(x, d, 0.0f, T_INF);
          if (walk_h.triangle != BVH_NONE) {
            walk_hit = true;
            q_t1 = walk_h.t;
          }
#endif
          q_mode = TRACK_DELTA;
          q_eval = false;
          state = ST_WALK;
          continue;
        }
#endif
        next_sample = true;
      } else {  // ST_WALK
        bool vertex = false;
        bool camera_ray = false;  // volpath's camera ray is its first walk ray
#if HAZE_VOLPATH
        camera_ray = depth == 0u;
#if HAZE_CHROMATIC
        if (!r.capped) beta *= r.T;  // the spectral tracking weight
#endif
        if (camera_ray && !r.capped) {
          // The camera ray's first vertex decides the term the path belongs to.
          to_surface = !r.hit;
          if (!r.hit) T_surf = trans_mean(r.T);
          t_j = r.t;
          if (!r.hit && !walk_hit) L_surf = beta * background(cam_d);
        }
#elif HAZE_CHROMATIC
        if (!r.capped) beta *= r.T;  // the spectral tracking weight
#endif
        if (r.capped) {
          // A walk the step cap stopped found no vertex: the path ends here (counted, biased).
        } else if (r.hit) {
          x = x + d * r.t;
          vec3 emitted = beta * r.ms.emit;
          if (to_surface)
            L_surf += emitted;
          else
            L_vol += emitted;
#if HAZE_VOLPATH
          // Absorption ends the path with probability 1 - mean albedo; scattering keeps the colour's ratio.
          float a = (r.ms.albedo.x + r.ms.albedo.y + r.ms.albedo.z) * (1.0f / 3.0f);
          vertex = rng_next(rng) < a;
          if (vertex) beta *= r.ms.albedo / a;
#else
          beta *= r.ms.albedo;
          vertex = true;
#endif
          g = r.ms.g;
          on_surface = false;
        }
#if HAZE_SURFACES
        else if (walk_hit) {
          // Emission of surfaces reached by the walk: NEE samples emissive triangles too, so the walk's share
          // is its MIS weight (with HAZE_MIS; else NEE alone counts it).
#if HAZE_MIS && HAZE_AREA
          GpuInstance inst = instances[walk_h.instance];
          if (!camera_ray && any(greaterThan(inst.emission.rgb, vec3(0.0f)))) {
            uint l = emitter_light(floatBitsToUint(inst.emission.w) + walk_h.primitive);
            float w = mis_power(p_walk, light_choice_pmf(l) * triangle_pdf(l, d, q_t1));
            if (to_surface)
              L_surf += beta * inst.emission.rgb * w;
            else
              L_vol += beta * inst.emission.rgb * w;
          }
#endif
          x = x + d * q_t1;
          n = dot(walk_h.normal, d) < 0.0f ? walk_h.normal : -walk_h.normal;
          ns = surface_normal(walk_h, n);
          alb = surface_albedo(walk_h);
          on_surface = true;
          vertex = true;
#if HAZE_VOLPATH
          if (camera_ray) {
            L_surf = beta * instances[walk_h.instance].emission.rgb;
#ifdef BINDING_acc_emit
            E_surf = L_surf;
#endif
            albedo0 = alb;
          }
#endif
        }
#endif
#if HAZE_MIS && HAZE_ENV
        else if (!camera_ray) {
          // The walk ray left the scene: delta tracking reached its end with probability T, so the
          // environment's radiance times the throughput and the walk's MIS weight (the sun is NEE's alone).
          vec3 Le = beta * environment_Le(d) * mis_power(p_walk, environment_light_pdf(d));
          if (to_surface)
            L_surf += Le;
          else
            L_vol += Le;
        }
#endif
        if (vertex) {
          depth += 1u;
#if HAZE_VOLPATH
          // Vertices beyond max_depth do no NEE (their emission is counted above, as in the default).
          do_nee = depth <= max_depth;
          next_sample = !do_nee;
#else
          float m = max(beta.x, max(beta.y, beta.z)) / beta_start;
          if (m < PATH_RR) {
            if (rng_next(rng) * PATH_RR >= m) {
              next_sample = true;
            } else {
              beta *= PATH_RR / m;
              do_nee = true;
            }
          } else {
            do_nee = true;
          }
#endif
        } else {
          next_sample = true;
        }
      }

      if (do_nee) {
        pending = vec3(0.0f);
        q_t1 = 0.0f;
#if HAZE_LIGHTS
        vec3 o = on_surface ? x + n * surface_epsilon(x) : x;
        LightSample ls = sample_light(o, vec3(rng_next(rng), rng_next(rng), rng_next(rng)));
#if HAZE_SURFACES
        if (on_surface)
          pending = beta * alb * (INV_PI * surface_cosine(n, ns, ls.wi)) * ls.Li;
        else
#endif
          pending = beta * hg_phase(dot(ls.wi, d), g) * ls.Li;
#if HAZE_MIS
        // The walk goes on from this vertex when depth < max_depth, and may then reach the same light: NEE's
        // share is the complementary power-heuristic weight (delta lights and the sun keep 1).
        if (depth < max_depth && ls.pdf > 0.0f && light_reached_by_walks(ls.light)) {
#if HAZE_SURFACES
          float p_w = on_surface ? surface_cosine(n, ns, ls.wi) * INV_PI : walk_phase_pdf(ls.wi, d, g);
#else
          float p_w = walk_phase_pdf(ls.wi, d, g);
#endif
          pending *= mis_power(ls.pdf, p_w);
        }
#endif
        bool visible = any(greaterThan(pending, vec3(0.0f)));
#if HAZE_SURFACES
        // Surfaces block shadow rays; an area light's own triangle is excluded by stopping just short of it.
        if (visible) visible = !bvh_occluded(o, ls.wi, 0.0f, ls.dist < T_INF ? ls.dist * 0.9999f : T_INF);
#endif
        if (visible) {
          q_o = o;
          q_d = ls.wi;
          q_t0 = 0.0f;
          q_t1 = min(ls.dist, media_exit(o, ls.wi));
#if !HAZE_VOLPATH
          // The roulette compares the shadow ray's contribution T c with rr_T, not T alone: c is pending
          // relative to the path's first vertex lit through an isotropic phase, so the shadow rays of dim
          // vertices (back-scattering, low throughput) stop early. c <= 16 bounds the work of bright ones.
          float c = max(pending.x, max(pending.y, pending.z)) /
                    max(beta_start * max(ls.Li.x, max(ls.Li.y, ls.Li.z)) * INV_4PI, 1e-30f);
          q_rr = min(rr_T / clamp(c, 1e-30f, 16.0f), 1.0f);
#endif
        } else {
          pending = vec3(0.0f);
        }
#endif
        // Without lights (or when blocked) the shadow query is empty and adds nothing.
        q_mode = TRACK_RATIO;
        q_eval = false;
        state = ST_SHADOW;
        continue;
      }

#if HAZE_WALK_SPLITS
      if (next_sample && split_left > 0u) {
        // The next walk from the saved vertex: the shadow state's walk step, with nothing pending.
        split_left -= 1u;
#if HAZE_WALK_SPLITS_AUTO
        split_walk_ended(split_walks, L_vol, walk_K);
#endif
        x = split_x;
        d = split_d;
        beta = split_beta;
        g = split_g;
        beta_start = split_beta_start;
        depth = 1u;
        on_surface = false;
        pending = vec3(0.0f);
        state = ST_SHADOW;
        known.T = Trans(0.0f);
        q_known = true;
        continue;
      }
#endif
      if (next_sample) break;
    }
#if HAZE_WALK_SPLITS_AUTO
    if (split_done) {
      split_walk_ended(split_walks, L_vol, walk_K);
      split_work += n_work - split_work0;
      split_S += split_walks_variance(split_walks, walk_K);
    }
#endif

#if HAZE_VOLPATH
    // The path's first medium vertex is the virtual point.
    float Y = luminance(L_vol);
    if (!(Y >= 0.0f && Y < 1e30f)) Y = 0.0f;
    vp_wt += Y * t_j;
    vp_w += Y;
#else
    if (pass > 0u) {
      // Volume sample j is complete: its luminance contribution weights its distance.
      float Y = luminance(L_vol - L_vol_start);
      if (!(Y >= 0.0f && Y < 1e30f)) Y = 0.0f;
      vp_wt += Y * t_j;
      vp_w += Y;
#if HAZE_GUIDE_HIST
      if (scene.guide_learn.y > 0.5f && P_guide > 0.0f) {
        // The sample's own estimate f(t)/q(t) of the ray integral (L_vol holds it divided by N): its mean in
        // a bin is the integral over the bin. Its square times q / q_Pi estimates the second moment at P_i.
        float L = Y * float(N);
        uint l = (guide_r.h / scene.guide_grid.z) * guide_learn_stride(GUIDE_BINS);
        uint b = guide_hist_bin(t_j, guide_r.R, GUIDE_BINS);
        if (b < GUIDE_BINS && L > 0.0f) guide_learn_add(l + b, L);
        guide_learn_add(l + GUIDE_BINS, 1.0f);
        // And into a vertex next to the pixel (stochastic bilinear; nothing more when it is the same one): a
        // histogram then learns from the rays around its own too, a less noisy pdf on short runs at the cost
        // of some blur (measured a gain on the beam and the sheets, docs/guiding.md).
        uint v_n = guide_vertex(guide_pos, rng);
        uint h_n = v_n * scene.guide_grid.z;
        if (h_n != guide_r.h) {
          uint l_n = v_n * guide_learn_stride(GUIDE_BINS);
          float R_n = guide_hist[h_n + 2u * GUIDE_BINS + 3u];
          if (R_n == 0.0f) {
            R_n = guide_vertex_range(uvec2(v_n % scene.guide_grid.x, v_n / scene.guide_grid.x));
            if (R_n > 0.0f) guide_learn[l_n + GUIDE_BINS + 1u + GUIDE_P_CHOICES] = R_n;
          }
          uint b_n = guide_hist_bin(t_j, R_n, GUIDE_BINS);
          if (b_n < GUIDE_BINS && L > 0.0f) guide_learn_add(l_n + b_n, L);
          guide_learn_add(l_n + GUIDE_BINS, 1.0f);
        }
        // Until the fold fixes R: the bounds' R (the same from every sample of the vertex), else the longest
        // segment (a racy max; a lost maximum only shortens R).
        uint l_max = l + GUIDE_BINS + 1u + GUIDE_P_CHOICES;
        if (guide_R_new && guide_R > 0.0f)
          guide_learn[l_max] = guide_R;
        else if (guide_R_new && t_g > guide_learn[l_max])
          guide_learn[l_max] = t_g;
        if (guide_r.total > 0.0f && L > 0.0f && q_j < T_INF)
          for (uint i = 0u; i < GUIDE_P_CHOICES; ++i)
            guide_learn_add(l + GUIDE_BINS + 1u + i,
                            min(L * L * guide_moment_factor(q_j, q_rest, q_guide, guide_p_choice(i)), 1e30f));
      }
#elif HAZE_GUIDING
      if (scene.guide_learn.y > 0.5f && P_guide > 0.0f) {
        // The sample's own estimate f(t)/q(t) of the ray integral (L_vol holds it divided by N).
        float L = Y * float(N);
        vec4 s_new = guide_update(guide_chosen, L, t_j, scene.guide_learn.z, scene.guide_learn.w);
        float p_write = guide_mean_w > 0.0f ? min(1.0f, L / guide_mean_w) : (L > 0.0f ? 1.0f : 0.0f);
        if (rng_next(rng) < p_write) guide_states[guide_slot(guide_pos, rng)] = s_new;
      }
#endif
    }
#endif
  }

  vec3 L = L_surf + L_vol;
  // Emission is not shaded by the albedo: dividing it by a dark albedo would make it a firefly for the
  // denoiser, which adds acc_emit back after remodulation instead.
  vec3 demod = (L_surf - E_surf) / max(albedo0, vec3(DEMOD_MIN_ALBEDO));
  counter_add(COUNT_LOOKUPS, n_lookups);
  counter_add(COUNT_DELTA_REAL, n_real);
  counter_add(COUNT_DELTA_NULL, n_null);
  counter_add(COUNT_DISTANCE, n_distance);
  counter_add(COUNT_GUIDED, n_guided);
  if (step_capped) counter_add(COUNT_STEP_CAP, 1u);
  if (violated) counter_add(COUNT_MAJORANT, 1u);
  // A non-finite sample never enters the sums: it is dropped, and the pixel's means leave it out of their
  // sample count (ACC_DROPPED); the frame's counter makes it visible.
  if (any(isnan(L)) || any(isinf(L)) || any(isnan(demod)) || any(isinf(demod)) || isnan(T_surf) ||
      isinf(T_surf)) {
    counter_add(COUNT_NON_FINITE, 1u);
    acc_surf[pixel].w += 1.0f;
    return;
  }
  bool clamped = false;
  acc_l[pixel] += vec4(L, T_surf);
  acc_l2[pixel] += vec4(square_capped(L, clamped), T_surf * T_surf);
  acc_vol[pixel] += vec4(L_vol, t_s < T_INF * 0.5f ? t_s : 0.0f);
  acc_vol2[pixel] += vec4(square_capped(L_vol, clamped), 0.0f);
  acc_surf[pixel] += vec4(L_surf, 0.0f);
  acc_surf2[pixel] += vec4(square_capped(L_surf, clamped), 0.0f);
  acc_demod[pixel] += vec4(demod, 0.0f);
  acc_demod2[pixel] += vec4(square_capped(demod, clamped), 0.0f);
#ifdef BINDING_acc_emit
  acc_emit[pixel] += vec4(E_surf, 0.0f);
#endif
  if (clamped) counter_add(COUNT_CLAMPED_SQUARES, 1u);
#if HAZE_WALK_SPLITS_AUTO
  if (split_learning)
    walk_splits_learn(pixel, walk_K, channel_sum(L), split_S, float(n_work - split_work),
                      float(split_work) / float(walk_K));
#endif
  acc_vp[pixel] += vec4(vp_wt, vp_w, vp_g, vp_gn);
}
