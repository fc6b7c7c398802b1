#version 460
// One camera sample per pixel per dispatch: the surface term T(0,t_s) L_bg and the volume term
// (N distance samples on [0, t_s] from the mixture q(t), NEE with ratio-tracked shadow rays, and a
// delta-tracked random walk for multiple scattering). Results are added to per-pixel sums and squares.
//
// The estimator runs as a small state machine whose loop issues one tracking query per iteration, so the
// tracker (and its single density-lookup call site) is inlined once.
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require

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
  uint counters[];  // COUNT_*
};

#include "lights/lights.glsl"
#include "volume/medium.glsl"
#if HAZE_SURFACES
#include "surfaces/material.glsl"
#endif
#if HAZE_GUIDING
#include "guiding/guide.glsl"
// K states per grid vertex, read and written by every sample (a Markov chain of states, not a histogram).
layout(std430, binding = BINDING_guide_states) buffer GuideStates {
  vec4 guide_states[];
};
#endif

layout(push_constant) uniform Push {
  uint sample_index;
}
pc;

const int ST_SURFACE = 0;  // ratio tracking T(0, t_s) for the surface term
const int ST_CAMERA = 1;   // ratio tracking T(0, t_j) to a sampled distance, with the medium at t_j
const int ST_SHADOW = 2;   // ratio tracking towards a light
const int ST_WALK = 3;     // delta tracking to the next scattering vertex

#if HAZE_GUIDING
// A random state slot at a grid vertex next to grid position g (stochastic bilinear choice of the vertex).
uint guide_slot(vec2 g, inout uint rng) {
  vec2 f = g - floor(g);
  ivec2 v = ivec2(floor(g)) + ivec2(rng_next(rng) < f.x ? 1 : 0, rng_next(rng) < f.y ? 1 : 0);
  v = clamp(v, ivec2(0), ivec2(scene.guide_grid.xy) - 1);
  uint K = scene.guide_grid.z;
  return (uint(v.y) * scene.guide_grid.x + uint(v.x)) * K + min(uint(rng_next(rng) * float(K)), K - 1u);
}
#endif

// x², capped at SQUARE_MAX (an overflow to Inf included); `clamped` tells whether any component was.
vec3 square_capped(vec3 x, inout bool clamped) {
  vec3 s = x * x;
  clamped = clamped || any(greaterThan(s, vec3(SQUARE_MAX)));
  return min(s, vec3(SQUARE_MAX));
}

// Offset of ray origins off a surface, relative to the scene's scale at that point.
float surface_epsilon(vec3 x) {
  return 1e-4f * max(1.0f, max(abs(x.x), max(abs(x.y), abs(x.z))));
}

void main() {
  uvec2 pix = gl_GlobalInvocationID.xy;
  uint W = scene.size.x, H = scene.size.y;
  if (pix.x >= W || pix.y >= H) return;
  uint pixel = pix.y * W + pix.x;
  uint rng = rng_init(scene.counts.w, pixel, pc.sample_index);

  vec2 jitter = scene.settings.z > 0.5f ? vec2(rng_next(rng), rng_next(rng)) : vec2(0.5f);
  vec3 cam_o = scene.cam_position.xyz;
  vec3 cam_d = camera_direction(scene.cam_right.xyz, scene.cam_up.xyz, scene.cam_forward.xyz,
                                vec2(pix) + jitter, vec2(W, H));
  float t_s = media_exit(cam_o, cam_d);
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

  vec3 L_surf = vec3(0.0f), L_vol = vec3(0.0f);
  vec3 albedo0 = vec3(1.0f);  // albedo of the camera's surface hit, for demodulation
  vec3 E_surf = vec3(0.0f);   // the camera hit's emission (in L_surf, kept out of the demodulated term)
  float T_surf = 1.0f;

  // Distance sampling on the camera ray: q(t) = (1 - P) [p_base q_base(t) + p_ea q_ea(t)] + P q_guide(t).
  float tau_total = maj_walk(cam_o, cam_d, 0.0f, t_s, T_INF).tau;
  float p_base = tau_total > 0.0f ? 1.0f : 0.0f;
  float p_ea = 0.0f;
#if HAZE_LOCAL
  uint K = scene.counts.z;
  if (K > 0u && t_s > 0.0f) {
    p_ea = tau_total > 0.0f ? scene.settings.x : 1.0f;
    p_base = 1.0f - p_ea;
  }
#endif
#if HAZE_GUIDING
  // The guide spreads its Gaussians over [0, t_g]: the ray up to t_s, but no further than a majorant optical
  // depth of GUIDE_MAX_TAU (light from beyond is negligible; q_base still covers it).
  float t_g = tau_total > GUIDE_MAX_TAU ? maj_walk(cam_o, cam_d, 0.0f, t_s, GUIDE_MAX_TAU).t : t_s;
  float P_guide = t_g > 0.0f && t_g < 1e18f ? scene.guide.x : 0.0f;
  vec2 guide_pos = (vec2(pix) + jitter) / scene.guide_learn.x;
  vec4 guide_chosen = vec4(0.0f);  // the state the current sample learns into
  float guide_mean_w = 0.0f;       // mean candidate weight, the bar for writing a state back
#endif
  float t_j = 0.0f;  // distance of the current volume sample
  vec3 L_vol_start = vec3(0.0f);
  // Virtual point sums (ACC_VP_*).
  float vp_wt = 0.0f, vp_w = 0.0f, vp_g = 0.0f, vp_gn = 0.0f;

  // Path state.
  int state = ST_SURFACE;
  vec3 q_o = cam_o, q_d = cam_d;
  float q_t0 = 0.0f, q_t1 = t_s;
  int q_mode = TRACK_RATIO;
  bool q_eval = false;
  uint j = 0u;              // volume sample index
  uint depth = 0u;          // scattering events so far (volume or surface)
  bool to_surface = false;  // the path belongs to the surface term (else to the volume term)
  vec3 x = cam_o;           // current vertex
  vec3 d = cam_d;           // direction the path travelled to reach x
  vec3 beta = vec3(0.0f);
  vec3 pending = vec3(0.0f);  // NEE contribution waiting for its shadow-ray transmittance
  float q_j = 1.0f;           // q(t_j) of the current distance sample
  float g = 0.0f;             // phase anisotropy at a volume vertex
  bool on_surface = false;    // the vertex is on a surface (normal n, albedo alb) rather than in a medium
  vec3 n = vec3(0.0f, 1.0f, 0.0f), alb = vec3(0.0f);
  vec3 ns = n;  // the shading normal (surfaces/material.glsl); n, the geometric one, offsets rays
  // Surface the current walk ray reaches if no medium stops it first.
  bool walk_hit = false;
#if HAZE_SURFACES
  BvhHit walk_h;
#endif

  for (;;) {
    TrackResult r = track(q_o, q_d, q_t0, q_t1, q_mode, q_eval, rng);
    bool next_sample = false;  // start the next volume sample
    bool do_nee = false;       // a scattering vertex is ready at x

    if (state == ST_SURFACE) {
      T_surf = r.T;
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
        depth = 1u;
        do_nee = max_depth > 0u && r.T > 0.0f;
        next_sample = !do_nee;
#endif
      } else {
        L_surf = r.T * background(cam_d);
        next_sample = true;
      }
    } else if (state == ST_CAMERA) {
      // r.T = T(0,t_j) estimate; the camera-ray contribution is T sigma (...) / q(t_j), averaged over N.
      float w = r.T * r.ms.sigma_t / (q_j * float(N));
      L_vol += w * r.ms.emit;
      if (max_depth > 0u && w > 0.0f) {
        beta = vec3(w) * r.ms.albedo;
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
      bool below = false;  // a bounce below the geometric surface reflects nothing (no light leaks)
      if (depth < max_depth) {
        if (on_surface) {
          // Lambertian: cosine sampling makes the weight the albedo.
          d = sample_cosine_hemisphere(ns, vec2(rng_next(rng), rng_next(rng)));
          beta *= alb;
          x += n * surface_epsilon(x);
          below = !(dot(d, n) > 0.0f);
        } else {
          d = hg_sample(d, g, vec2(rng_next(rng), rng_next(rng)));
        }
      }
      if (depth < max_depth && !below) {
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
      if (r.hit) {
        x = x + d * r.t;
        vec3 emitted = beta * r.ms.emit;
        if (to_surface)
          L_surf += emitted;
        else
          L_vol += emitted;
        beta *= r.ms.albedo;
        g = r.ms.g;
        on_surface = false;
        vertex = true;
      }
#if HAZE_SURFACES
      else if (walk_hit) {
        // Emission of surfaces reached by the walk is counted by NEE, which samples emissive triangles.
        x = x + d * q_t1;
        n = dot(walk_h.normal, d) < 0.0f ? walk_h.normal : -walk_h.normal;
        ns = surface_normal(walk_h, n);
        alb = surface_albedo(walk_h);
        on_surface = true;
        vertex = true;
      }
#endif
      if (vertex) {
        depth += 1u;
        float m = max(beta.x, max(beta.y, beta.z));
        if (m < 0.25f) {
          if (rng_next(rng) * 0.25f >= m) {
            next_sample = true;
          } else {
            beta *= 0.25f / m;
            do_nee = true;
          }
        } else {
          do_nee = true;
        }
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

    if (next_sample) {
      to_surface = false;
      if (j > 0u) {
        // Volume sample j is complete: its luminance contribution weights its distance.
        float Y = luminance(L_vol - L_vol_start);
        if (!(Y >= 0.0f && Y < 1e30f)) Y = 0.0f;
        vp_wt += Y * t_j;
        vp_w += Y;
#if HAZE_GUIDING
        if (scene.guide_learn.y > 0.5f && P_guide > 0.0f) {
          // The sample's own estimate f(t)/q(t) of the ray integral (L_vol holds it divided by N).
          float L = Y * float(N);
          vec4 s_new = guide_update(guide_chosen, L, t_j, scene.guide_learn.z, scene.guide_learn.w);
          float p_write = guide_mean_w > 0.0f ? min(1.0f, L / guide_mean_w) : (L > 0.0f ? 1.0f : 0.0f);
          if (rng_next(rng) < p_write) guide_states[guide_slot(guide_pos, rng)] = s_new;
        }
#endif
      }
      if (j >= N || (p_base + p_ea) == 0.0f) break;
      j += 1u;
      L_vol_start = L_vol;
      // Draw t_j from the mixture and evaluate q(t_j).
      float t;
      MajWalk mw;
      float u_pick = rng_next(rng);
      float u_t = rng_next(rng);
      float P = 0.0f;
#if HAZE_GUIDING
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
        } else {
          u_pick = (u_pick - P) / (1.0f - P);
        }
      }
#endif
      if (u_pick > 1.5f) {
        mw = maj_walk(cam_o, cam_d, 0.0f, t, T_INF);
      } else if (u_pick < p_base) {
        mw = maj_walk(cam_o, cam_d, 0.0f, t_s, truncated_exp_sample_tau(tau_total, u_t));
        t = mw.t;
      } else {
#if HAZE_LOCAL
        uint k = min(uint((u_pick - p_base) / p_ea * float(K)), K - 1u);
        t = equi_angular_sample(equi_angular_setup(cam_o, cam_d, lights[k].position.xyz, 0.0f, t_s), u_t);
#else
        t = 0.0f;
#endif
        t = clamp(t, 0.0f, t_s);
        mw = maj_walk(cam_o, cam_d, 0.0f, t, T_INF);
      }
      float q = p_base > 0.0f ? p_base * mw.sigma * truncated_exp_pdf_tau(mw.tau, tau_total) : 0.0f;
#if HAZE_LOCAL
      for (uint k = 0u; k < K; ++k)
        q += p_ea / float(K) *
             equi_angular_pdf(equi_angular_setup(cam_o, cam_d, lights[k].position.xyz, 0.0f, t_s), t);
#endif
#if HAZE_GUIDING
      q = (1.0f - P) * q + P * guide_mixture_pdf(gm, t);
#endif
      if (!(q > 0.0f)) {
        // A sample the mixture cannot produce again contributes nothing.
        q = T_INF;
      }
      q_j = q;
      t_j = t;
      x = cam_o + cam_d * t;
      d = cam_d;
      q_o = cam_o;
      q_d = cam_d;
      q_t0 = 0.0f;
      q_t1 = t;
      q_mode = TRACK_RATIO;
      q_eval = true;
      state = ST_CAMERA;
    }
  }

  vec3 L = L_surf + L_vol;
  // Emission is not shaded by the albedo: dividing it by a dark albedo would make it a firefly for the
  // denoiser, which adds acc_emit back after remodulation instead.
  vec3 demod = (L_surf - E_surf) / max(albedo0, vec3(DEMOD_MIN_ALBEDO));
  // Non-finite values never enter the sums (extreme inputs are clamped, not propagated).
  if (any(isnan(L)) || any(isinf(L)) || any(isnan(demod)) || any(isinf(demod))) {
    L = vec3(0.0f);
    L_vol = vec3(0.0f);
    L_surf = vec3(0.0f);
    demod = vec3(0.0f);
    E_surf = vec3(0.0f);
    atomicAdd(counters[COUNT_NON_FINITE], 1u);
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
  if (clamped) atomicAdd(counters[COUNT_CLAMPED_SQUARES], 1u);
  acc_vp[pixel] += vec4(vp_wt, vp_w, vp_g, vp_gn);
}
