// The medium seen by the tracker: sigma_t at a point (with the stochastic choice of the scattering
// component), the piecewise-constant majorant along a ray, and ratio/delta tracking on top of them.
// Reads the scene block and, with HAZE_HETERO, the bindings "grids" (every grid's device address, read by
// PNanoVDB: volume/grids.glsl), "media", and "majorant" or, with HAZE_MINORANT (scenes of the default
// estimator), "minorant", whose pairs hold the majorants too (volume/media.hpp).
#ifndef HAZE_MEDIUM_GLSL
#define HAZE_MEDIUM_GLSL

#if HAZE_HETERO
#include "volume/grids.glsl"
layout(std430, binding = BINDING_media) readonly buffer MediaBuffer {
  GpuMedium media[];
};
#if !HAZE_MINORANT
layout(std430, binding = BINDING_majorant) readonly buffer MajorantBuffer {
  float majorant[];
};
#endif
#endif
#if HAZE_MINORANT
// Two pairs per majorant cell (volume/media.cpp): (majorant, minorant) for delta tracking's decomposition,
// and (control, residual majorant) for residual ratio tracking: the cell's mean density c and
// max(majorant - c, c - minorant). A tracker reads the pair its mode needs, one load per DDA step.
layout(std430, binding = BINDING_minorant) readonly buffer MinorantBuffer {
  vec2 minorant[];
};
#endif

// A transmittance or tracking weight: one per channel in chromatic media (HAZE_CHROMATIC), else one.
#if HAZE_CHROMATIC
#define Trans vec3
HAZE_INLINE float trans_max(vec3 T) {
  return max(T.x, max(T.y, T.z));
}
HAZE_INLINE float trans_mean(vec3 T) {
  return (T.x + T.y + T.z) * (1.0f / 3.0f);
}
#else
#define Trans float
HAZE_INLINE float trans_max(float T) {
  return T;
}
HAZE_INLINE float trans_mean(float T) {
  return T;
}
#endif

struct MediumSample {
  float sigma_t;    // total extinction (chromatic: the sum of the components' unscaled sigma_t)
  float sigma_het;  // the grid media's part of sigma_t, summed apart from the haze (residual tracking takes
                    // the haze in closed form; (haze + grids) - haze would lose the grids' low bits)
  vec3 albedo;      // of the chosen component (chosen with probability sigma_t,i / sigma_t)
  float g;
  vec3 emit;  // (1 - albedo_i) * Le_i of the chosen component: E[sigma_t * emit] = sigma_a * Le
#if HAZE_CHROMATIC
  vec3 sigma_c;      // sigma_t per channel, exactly: sum over components of sigma_t,i * sigma_t_color_i
  vec3 sigma_c_het;  // its grid media's part (as sigma_het)
  vec3 color;        // the chosen component's sigma_t_color: E[sigma_t * color * X_i] = sum_i sigma_t,i,c X_i
#endif
};

// Transmittance of a haze optical depth tau (of the unscaled sigma_t) per channel.
HAZE_INLINE Trans haze_transmittance(float tau) {
#if HAZE_CHROMATIC
  return exp(-tau * scene.haze_sigma_t_color.rgb);
#else
  return exp(-tau);
#endif
}

HAZE_INLINE vec2 ray_box(vec3 o, vec3 d, vec3 bmin, vec3 bmax) {
  vec3 inv = 1.0f / d;  // +-inf for axis-parallel rays is what the slab test wants
  vec3 ta = (bmin - o) * inv, tb = (bmax - o) * inv;
  vec3 tmin = min(ta, tb), tmax = max(ta, tb);
  // NaN (0 * inf on a slab plane) must not poison the result: max/min ignore it in GLSL only sometimes.
  float t0 = max(max(isnan(tmin.x) ? -T_INF : tmin.x, isnan(tmin.y) ? -T_INF : tmin.y),
                 isnan(tmin.z) ? -T_INF : tmin.z);
  float t1 = min(min(isnan(tmax.x) ? T_INF : tmax.x, isnan(tmax.y) ? T_INF : tmax.y),
                 isnan(tmax.z) ? T_INF : tmax.z);
  return vec2(t0, t1);
}

HAZE_INLINE bool inside_box(vec3 x, vec3 bmin, vec3 bmax) {
  return all(greaterThanEqual(x, bmin)) && all(lessThanEqual(x, bmax));
}

// Far end of everything that holds a medium, seen from o along d (0 when nothing is hit).
float media_exit(vec3 o, vec3 d) {
  float t = 0.0f;
#if HAZE_HAZE
  vec2 h = ray_box(o, d, scene.haze_min.xyz, scene.haze_max.xyz);
  if (h.x <= h.y && h.y > 0.0f) t = max(t, h.y);
#endif
#if HAZE_HETERO
  vec2 g = ray_box(o, d, scene.maj_min.xyz, scene.maj_max.xyz);
  if (g.x <= g.y && g.y > 0.0f) t = max(t, g.y);
#endif
  return min(t, T_INF);
}

// The homogeneous haze at x (nothing outside its box): the whole medium where no grid reaches.
MediumSample haze_at(vec3 x) {
  MediumSample ms;
  ms.sigma_t = 0.0f;
  ms.sigma_het = 0.0f;
  ms.albedo = vec3(0.0f);
  ms.g = 0.0f;
  ms.emit = vec3(0.0f);
#if HAZE_CHROMATIC
  ms.sigma_c = vec3(0.0f);
  ms.sigma_c_het = vec3(0.0f);
  ms.color = vec3(1.0f);
#endif
#if HAZE_HAZE
  if (inside_box(x, scene.haze_min.xyz, scene.haze_max.xyz)) {
#if HAZE_CHROMATIC
    ms.sigma_c = scene.haze_min.w * scene.haze_sigma_t_color.rgb;
    ms.color = scene.haze_sigma_t_color.rgb;
#endif
    ms.sigma_t = scene.haze_min.w;
    ms.albedo = scene.haze_albedo_g.rgb;
    ms.g = scene.haze_albedo_g.w;
  }
#endif
  return ms;
}

#if HAZE_HETERO
#if HAZE_STOCHASTIC_LOOKUP && HAZE_ONE_GRID
// The one grid medium's density accessor, kept over a sample's lookups (media_begin_sample).
pnanovdb_readaccessor_t density_acc;
#endif
// Before a sample's first lookup.
void media_begin_sample() {
#if HAZE_STOCHASTIC_LOOKUP && HAZE_ONE_GRID
  density_acc = grid_accessor(media[0].grid.x);
#endif
}

// The density grid of medium m at index position p: trilinear, or with HAZE_STOCHASTIC_LOOKUP one voxel of
// its footprint chosen by the trilinear weights with the uniform u_voxel (an unbiased estimate at an eighth
// of the reads; the trackers use sigma_t linearly).
float medium_density(uint m, vec3 p, float u_voxel) {
#if HAZE_STOCHASTIC_LOOKUP && HAZE_ONE_GRID
  return grid_voxel(media[m].grid.x, p, u_voxel, density_acc);
#elif HAZE_STOCHASTIC_LOOKUP
  pnanovdb_readaccessor_t acc = grid_accessor(media[m].grid.x);
  return grid_voxel(media[m].grid.x, p, u_voxel, acc);
#else
  return grid_trilinear(media[m].grid.x, p);
#endif
}
#endif

// sigma_t at x, and one component chosen with probability sigma_t,i / sigma_t using the single uniform u
// (streaming selection: u is rescaled after each decision). u_voxel: the density lookups' voxel choice
// (medium_density).
MediumSample sample_medium(vec3 x, float u, float u_voxel) {
  MediumSample ms = haze_at(x);
#if HAZE_HETERO
  int chosen = -1;
  vec3 chosen_p = vec3(0.0f);
  [[dont_unroll]] for (uint m = 0u; m < scene.counts.x; ++m) {
    if (!inside_box(x, media[m].world_min.xyz, media[m].world_max.xyz)) continue;
    vec3 p = (media[m].world_to_index * vec4(x, 1.0f)).xyz;
    // Negative or non-finite voxel values count as empty space.
    float s = media[m].world_min.w * medium_density(m, p, u_voxel);
    if (!(s > 0.0f) || isinf(s)) continue;
    ms.sigma_t += s;
    ms.sigma_het += s;
#if HAZE_CHROMATIC
    ms.sigma_c += s * media[m].sigma_t_color.rgb;
    ms.sigma_c_het += s * media[m].sigma_t_color.rgb;
#endif
    float p_take = s / ms.sigma_t;
    if (u < p_take) {
      chosen = int(m);
      chosen_p = p;
      u = u / p_take;
    } else {
      u = (u - p_take) / (1.0f - p_take);
    }
  }
  if (chosen >= 0) {
    ms.albedo = media[chosen].albedo_g.rgb;
    ms.g = media[chosen].albedo_g.w;
#if HAZE_CHROMATIC
    ms.color = media[chosen].sigma_t_color.rgb;
#endif
#if HAZE_EMISSION
    uint mode = media[chosen].grid.z;
    if (mode != 0u) {
      float v = max(grid_trilinear(media[chosen].grid.y, chosen_p), 0.0f);
      vec3 Le = mode == 1u ? vec3(v) : blackbody_rgb(v * media[chosen].emission.x);
      ms.emit = (vec3(1.0f) - ms.albedo) * media[chosen].world_max.w * Le;
    }
#endif
  }
#endif
  return ms;
}

// Piecewise-constant majorant along a ray: the heterogeneous part from a 3D DDA over the majorant grid,
// the haze part from its box. Segments break at cell and box boundaries.
struct MajorantIter {
  float t, t1;
  float h0, h1;  // haze interval
  float g0, g1;  // majorant-grid interval
  // HAZE_MINORANT: the pair (0 or 1, above) maj_next reads, and its value for the segment it returned last
  // ((0, 0) outside the grid); the segment's sigma_het is then the pair's bound, x + y for pair 1.
  uint pair;
  vec2 control;
  ivec3 cell;
  ivec3 step;
  vec3 t_max, t_delta;
};

MajorantIter maj_init(vec3 o, vec3 d, float t0, float t1) {
  MajorantIter it;
  it.t = t0;
  it.t1 = t1;
  it.h0 = T_INF;
  it.h1 = -T_INF;
  it.g0 = T_INF;
  it.g1 = -T_INF;
#if HAZE_HAZE
  vec2 h = ray_box(o, d, scene.haze_min.xyz, scene.haze_max.xyz);
  if (h.x <= h.y) {
    it.h0 = h.x;
    it.h1 = h.y;
  }
#endif
#if HAZE_HETERO
  vec2 g = ray_box(o, d, scene.maj_min.xyz, scene.maj_max.xyz);
  if (g.x <= g.y) {
    it.g0 = g.x;
    it.g1 = g.y;
  }
#endif
  it.pair = 0u;
  it.control = vec2(0.0f);
  it.cell = ivec3(0);
  it.step = ivec3(0);
  it.t_max = vec3(0.0f);
  it.t_delta = vec3(0.0f);
#if HAZE_HETERO
  // The DDA starts where the ray enters the grid (or at t0 inside it).
  if (it.g0 <= it.g1) {
    vec3 cs = (scene.maj_max.xyz - scene.maj_min.xyz) / vec3(scene.maj_res.xyz);
    vec3 p = (o + d * max(it.g0, t0) - scene.maj_min.xyz) / cs;
    it.cell = clamp(ivec3(floor(p)), ivec3(0), ivec3(scene.maj_res.xyz) - 1);
    it.step = ivec3(sign(d));
    vec3 next = scene.maj_min.xyz + (vec3(it.cell) + max(vec3(it.step), vec3(0.0f))) * cs;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0.0f) {
        it.t_max[a] = T_INF;
        it.t_delta[a] = T_INF;
      } else {
        it.t_max[a] = (next[a] - o[a]) / d[a];
        it.t_delta[a] = cs[a] / abs(d[a]);
      }
    }
  }
#endif
  return it;
}

// Next segment [t_a, t_b) with majorants split into heterogeneous and haze parts. False at the end.
bool maj_next(INOUT(MajorantIter) it, OUT(float) sigma_het, OUT(float) sigma_haze, OUT(float) t_a,
              OUT(float) t_b) {
  sigma_het = 0.0f;
  sigma_haze = 0.0f;
  it.control = vec2(0.0f);
  t_a = it.t;
  t_b = it.t1;
  if (!(it.t < it.t1)) return false;
#if HAZE_HAZE
  if (t_a < it.h0) {
    t_b = min(t_b, it.h0);
  } else if (t_a < it.h1) {
    sigma_haze = scene.haze_min.w;
    t_b = min(t_b, it.h1);
  }
#endif
#if HAZE_HETERO
  if (t_a < it.g0) {
    t_b = min(t_b, it.g0);
  } else if (t_a < it.g1) {
    ivec3 r = ivec3(scene.maj_res.xyz);
    uint cell = uint((it.cell.z * r.y + it.cell.y) * r.x + it.cell.x);
#if HAZE_MINORANT
    it.control = minorant[2u * cell + it.pair];
    sigma_het = it.pair == 0u ? it.control.x : it.control.x + it.control.y;
#else
    sigma_het = majorant[cell];
#endif
    float t_exit = max(min(min(it.t_max.x, it.t_max.y), it.t_max.z), t_a);
    t_exit = min(t_exit, it.g1);
    if (t_exit <= t_b) {
      t_b = t_exit;
      // Step the DDA into the next cell; leaving the grid ends its interval here.
      int a =
          it.t_max.x <= it.t_max.y ? (it.t_max.x <= it.t_max.z ? 0 : 2) : (it.t_max.y <= it.t_max.z ? 1 : 2);
      it.cell[a] += it.step[a];
      it.t_max[a] += it.t_delta[a];
      if (it.cell[a] < 0 || it.cell[a] >= r[a]) it.g1 = t_exit;
    }
  }
#endif
  it.t = t_b;
  return true;
}

// Optical depth of the full majorant from t0 up to where it reaches tau_stop (or t1).
struct MajWalk {
  float tau;      // accumulated majorant optical depth
  float tau_het;  // its heterogeneous part (the majorant grid's)
  float t;        // where the walk stopped
  float sigma;    // majorant at t
};

MajWalk maj_walk(vec3 o, vec3 d, float t0, float t1, float tau_stop) {
  MajWalk w;
  w.tau = 0.0f;
  w.tau_het = 0.0f;
  w.t = t0;
  w.sigma = 0.0f;
  MajorantIter it = maj_init(o, d, t0, t1);
  float s_het, s_haze, ta, tb;
  uint steps = 0u;
  while (maj_next(it, s_het, s_haze, ta, tb) && steps++ < scene.maj_res.w) {
    float s = s_het + s_haze;
    float dtau = s * (tb - ta);
    w.sigma = s;
    if (w.tau + dtau >= tau_stop && s > 0.0f) {
      w.t = ta + (tau_stop - w.tau) / s;
      w.tau_het += s_het * (w.t - ta);
      w.tau = tau_stop;
      return w;
    }
    w.tau += dtau;
    w.tau_het += s_het * (tb - ta);
    w.t = tb;
  }
  return w;
}

const int TRACK_RATIO = 0;  // transmittance estimate T over [t0, t1]
const int TRACK_DELTA = 1;  // first real collision in [t0, t1]

// Whether ratio tracking takes the haze in closed form (the default estimator) or tracks it (volpath).
#if HAZE_VOLPATH
const bool TRACK_CONTROL = false;  // plain ratio tracking: every medium is tracked, the haze included
#else
const bool TRACK_CONTROL = true;  // the haze's transmittance in closed form (residual ratio tracking)
#endif

struct TrackResult {
  Trans T;  // RATIO: the transmittance estimate; DELTA: 1 (grey) or the spectral tracking weight (chromatic)
  bool hit;
  float t;
  MediumSample ms;  // at the collision (DELTA) or at t1 (RATIO with eval_end)
  uint lookups;     // density evaluations
  uint nulls;       // DELTA: tentative collisions that were null
  bool capped;      // the step cap stopped the query: T = 0 (RATIO) or no collision (DELTA), not an estimate
  bool violated;    // sigma_t above the majorant at a lookup: the estimate is biased there
};

// sigma above the majorant sigma_maj by more than float rounding of the trilinear weights.
HAZE_INLINE bool above_majorant(float sigma, float sigma_maj) {
  return sigma > sigma_maj * 1.00001f;
}
// sigma below the minorant sigma_min by more than the same rounding.
HAZE_INLINE bool below_minorant(float sigma, float sigma_min) {
  return sigma < sigma_min * 0.99999f;
}

#if HAZE_CHROMATIC
// Spectral tracking (Kutz et al. 2017) at a tentative collision of delta tracking in chromatic media: real
// with probability P_r = max_c(sigma_c W_c) / (max_c(sigma_c W_c) + max_c(sigma_n,c W_c)), null otherwise
// (sigma_n,c = sigma_maj - sigma_c), the weight W multiplied by (sigma_event,c / sigma_maj) / P_event, so
// that E[W_c at the collision] is channel c's own collision density. The real event's sigma_c is the
// chosen component's sigma_t * color (its choice with probability sigma_t,i / sigma_t, medium.glsl above).
// A path whose weights are all 0 ends without a collision (W = 0).
bool spectral_collision(INOUT(vec3) W, MediumSample ms, float sigma_maj, INOUT(uint) rng) {
  vec3 sigma_n = max(vec3(sigma_maj) - ms.sigma_c, vec3(0.0f));
  float P_r = trans_max(ms.sigma_c * W), P_n = trans_max(sigma_n * W);
  if (!(P_r + P_n > 0.0f)) {
    W = vec3(0.0f);
    return false;
  }
  float p_r = P_r / (P_r + P_n);
  if (rng_next(rng) < p_r) {
    W *= ms.sigma_t * ms.color / (sigma_maj * p_r);
    return true;
  }
  W *= sigma_n / (sigma_maj * (1.0f - p_r));
  return false;
}
#endif

#if HAZE_DECOMPOSITION
// A collision with the scene's one grid medium (grey, without emission): constants, no lookup.
MediumSample grid_medium_collision() {
  MediumSample ms;
  ms.sigma_t = 0.0f;  // not read after a delta-tracked collision
  ms.sigma_het = 0.0f;
  ms.albedo = media[0].albedo_g.rgb;
  ms.g = media[0].albedo_g.w;
  ms.emit = vec3(0.0f);
  return ms;
}
#endif

// Ratio tracking (default estimator) is residual ratio tracking (Novak et al. 2014): the control, the haze
// and with HAZE_MINORANT the cell's mean density c per segment, is taken in closed form and only the
// residual sigma_t - c is tracked, under the residual majorant max(hi - c, c - lo) of the cell's bounds
// [lo, hi] (a segment where both bounds meet needs no lookup). A residual of either sign gives the weight
// 1 - (sigma_t - c) / residual majorant in [0, 2]; with c at the mean the residual is small on average
// (less variance) and its majorant at most hi - lo (fewer lookups than the minorant as the control). Each
// loop iteration does at most one lookup. rr, rr_survive: Russian roulette on T below rr, surviving with
// rr_survive.
TrackResult track(vec3 o, vec3 d, float t0, float t1, int mode, bool eval_end, float rr, float rr_survive,
                  float tau_first, INOUT(uint) rng) {
  TrackResult r;
  r.T = Trans(1.0f);
  r.hit = false;
  r.t = t1;
  r.ms.sigma_t = 0.0f;
  r.ms.sigma_het = 0.0f;
  r.ms.albedo = vec3(0.0f);
  r.ms.g = 0.0f;
  r.ms.emit = vec3(0.0f);
#if HAZE_CHROMATIC
  r.ms.sigma_c = vec3(0.0f);
  r.ms.sigma_c_het = vec3(0.0f);
  r.ms.color = vec3(1.0f);
#endif
  r.lookups = 0u;
  r.nulls = 0u;
  r.capped = false;
  r.violated = false;
  bool control = TRACK_CONTROL && mode == TRACK_RATIO;
  MajorantIter it = maj_init(o, d, t0, t1);
#if HAZE_MINORANT
  it.pair = control ? 1u : 0u;
#endif
  float s_het = 0.0f, s_haze = 0.0f, ta = t0, tb = t0;
  float sigma_maj = 0.0f;
  float sigma_c = 0.0f;   // the grid's control on this segment (all channels)
  float sigma_lo = 0.0f;  // the bounds the tracked sigma_t must keep on it (else a violation is counted)
  float sigma_hi = 0.0f;
  float tau_control = 0.0f;  // the haze's optical depth (unscaled)
  float tau_min = 0.0f;      // the grid control's
#if HAZE_MINORANT
  // The roulette when T times the control's transmittance falls below rr, i.e. when the control's optical
  // depth passes tau_rr = log(max T / rr): a comparison per segment, not an exp. Chromatic: the haze's
  // smallest multiplier (T times the control's transmittance is at most that).
#if HAZE_CHROMATIC
  const float c_haze =
      min(scene.haze_sigma_t_color.r, min(scene.haze_sigma_t_color.g, scene.haze_sigma_t_color.b));
#else
  const float c_haze = 1.0f;
#endif
  float tau_rr = log(1.0f / rr);
#endif
  float t = t0;
  float tau_left = tau_first >= 0.0f ? tau_first : -log_one_minus(rng_next(rng));
  bool end_done = !eval_end;
  uint steps = 0u;
  for (;;) {
    // Advance over segments (no lookups) until the next tentative collision or the end.
    bool found = false, killed = false;
    for (;;) {
      if (!(t < tb)) {
        if (!maj_next(it, s_het, s_haze, ta, tb)) break;
        t = ta;
        sigma_maj = control ? s_het : s_het + s_haze;
#if HAZE_CHROMATIC
        // The majorant of every channel: the grey one times the largest multiplier.
        sigma_maj *= scene.haze_sigma_t_color.w;
#endif
        if (control) tau_control += s_haze * (tb - ta);
        sigma_hi = sigma_maj;
#if HAZE_MINORANT
        if (control) {
          // Every channel's sigma_t of the grids lies in [m_min lo, m_max hi] (m: the multipliers); with the
          // control m_min c, m_max (c + r) - m_min c bounds the residual both ways (grey: r).
          sigma_c = it.control.x * scene.maj_min.w;
          sigma_maj = max(sigma_maj - sigma_c, 0.0f);
          sigma_lo = sigma_c - sigma_maj;
          sigma_hi = sigma_c + sigma_maj;
        }
        tau_min += sigma_c * (tb - ta);
        // The roulette also at each segment: where the control alone takes T below rr (deep shadow rays),
        // the query ends before its next lookup.
        if (control && tau_min + c_haze * tau_control > tau_rr) {
          if (rng_next(rng) >= rr_survive) {
            killed = true;
            break;
          }
          r.T /= rr_survive;
          tau_rr -= log(rr_survive);
        }
#endif
      }
      float dt = tb - t;
      if (sigma_maj * dt > tau_left) {
        t += tau_left / sigma_maj;
        found = true;
        break;
      }
      tau_left -= sigma_maj * dt;
      t = tb;
    }
    if (killed) {
      r.T = Trans(0.0f);
      break;
    }
    if (!found && end_done) break;
    bool at_end = !found;
    vec3 x = o + d * (at_end ? t1 : t);
#if HAZE_DECOMPOSITION
    // Delta tracking as decomposition tracking (Kutz et al. 2017): a tentative collision is real with
    // probability sigma_t / sigma_maj either way, but where the uniform falls under the control (the haze and
    // the cell's minorant) it is real whatever the density: no lookup. The one grey medium has no emission,
    // so its albedo and g are all a collision needs.
    float u_delta = 0.0f;
    if (mode == TRACK_DELTA && !at_end) {
      u_delta = rng_next(rng) * sigma_maj;
      if (u_delta < s_haze + it.control.y) {
        r.hit = true;
        r.t = t;
        r.ms = u_delta < s_haze ? haze_at(x) : grid_medium_collision();
        break;
      }
    }
#endif
#if HAZE_STOCHASTIC_LOOKUP
    float u_voxel = rng_next(rng);
#else
    const float u_voxel = 0.5f;
#endif
    MediumSample ms = sample_medium(x, rng_next(rng), u_voxel);
    r.lookups += 1u;
    // The part of sigma_t this query's majorant bounds (the haze's control is exact); checked against both
    // bounds before the minorant's control is taken off.
#if HAZE_CHROMATIC
    vec3 sigma = control ? ms.sigma_c_het : ms.sigma_c;
    r.violated = r.violated || above_majorant(trans_max(sigma), sigma_hi) ||
                 below_minorant(min(sigma.x, min(sigma.y, sigma.z)), sigma_lo);
#else
    float sigma = control ? ms.sigma_het : ms.sigma_t;
    r.violated = r.violated || above_majorant(sigma, sigma_hi) || below_minorant(sigma, sigma_lo);
#endif
#if HAZE_DECOMPOSITION
    // Delta tracking's control: the haze and the cell's minorant.
    if (mode == TRACK_DELTA) r.violated = r.violated || below_minorant(ms.sigma_het, it.control.y);
#endif
    sigma -= sigma_c;
    if (at_end) {
      r.ms = ms;
      break;
    }
    if (mode == TRACK_RATIO) {
      // pbrt-v4 clamps the null-collision weight at 0 too; a violation is counted above. Below the control
      // the weight exceeds 1 (at most 2). Chromatic: ratio tracking per channel under the common majorant.
      r.T *= clamp(Trans(1.0f) - sigma / sigma_maj, 0.0f, 2.0f);
#if HAZE_MINORANT
      // The roulette sees the whole estimate, the control's transmittance so far included (on the residual's
      // T alone it comes later: more lookups than without the minorant).
      tau_rr = log(trans_max(r.T) / rr);
      if (tau_min + c_haze * tau_control > tau_rr) {
#else
      if (trans_max(r.T) < rr) {
#endif
        // Russian roulette keeps the estimate unbiased while bounding the walk.
        if (rng_next(rng) >= rr_survive) {
          r.T = Trans(0.0f);
          break;
        }
        r.T /= rr_survive;
#if HAZE_MINORANT
        tau_rr -= log(rr_survive);
#endif
      }
    }
#if HAZE_CHROMATIC
    else if (spectral_collision(r.T, ms, sigma_maj, rng)) {
#elif HAZE_DECOMPOSITION
    else if (u_delta < ms.sigma_t) {
      // Above the control: the collision is the residual's, the grid medium's (the haze is all control).
      ms = grid_medium_collision();
#else
  else if (rng_next(rng) * sigma_maj < ms.sigma_t) {
#endif
      r.hit = true;
      r.t = t;
      r.ms = ms;
      break;
    } else {
      r.nulls += 1u;
#if HAZE_CHROMATIC
      if (mode == TRACK_DELTA && trans_max(r.T) == 0.0f) break;  // no channel carries anything further
#endif
    }
    tau_left = -log_one_minus(rng_next(rng));
    // Bounded work per query: a pathological majorant cannot hang the dispatch. What was cut is counted.
    if (++steps >= scene.maj_res.w) {
      r.T = Trans(0.0f);
      r.capped = true;
      break;
    }
  }
  if (control) r.T *= haze_transmittance(tau_control) * exp(-tau_min);
  return r;
}

#endif
