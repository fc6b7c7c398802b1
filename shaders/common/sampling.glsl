// Sampling routines and their pdfs, shared by the shaders and the CPU tests (chi-square tests call these).
#ifndef HAZE_SAMPLING_GLSL
#define HAZE_SAMPLING_GLSL
#include "common/compat.glsl"

// 1 - exp(-x) without cancellation for small x (GLSL has no expm1).
HAZE_INLINE float one_minus_exp_neg(float x) {
  return x < 1e-3f ? x * (1.0f - x * 0.5f * (1.0f - x * (1.0f / 3.0f))) : 1.0f - exp(-x);
}

// log(1 - x) for x in [0, 1), accurate for small x.
HAZE_INLINE float log_one_minus(float x) {
  return x < 1e-4f ? -x * (1.0f + 0.5f * x) : log(1.0f - x);
}

// One corner of a trilinear cell (0 or 1 per axis) for the fractional position f, chosen with probability
// equal to its trilinear weight: axis a is 1 with probability f[a], independently. One uniform u serves the
// three axes (streaming: u is rescaled after each decision, so every decision's probability is exact to
// about 2^-24 of the branch that reaches it). The value at that corner is an unbiased one-read estimate of
// the trilinear interpolation.
HAZE_INLINE ivec3 trilinear_corner(vec3 f, float u) {
  ivec3 c = ivec3(0);
  for (int a = 0; a < 3; ++a) {
    if (u < f[a]) {
      c[a] = 1;
      u = u / f[a];
    } else {
      u = (u - f[a]) / (1.0f - f[a]);
    }
    u = min(u, 0.99999994f);  // rounding must not carry u to 1
  }
  return c;
}

// Orthonormal basis around a unit vector n (Duff et al. 2017).
HAZE_INLINE vec3 onb_to_world(vec3 n, vec3 local) {
  float s = n.z >= 0.0f ? 1.0f : -1.0f;
  float a = -1.0f / (s + n.z);
  float b = n.x * n.y * a;
  vec3 t = vec3(1.0f + s * n.x * n.x * a, s * b, -s * n.x);
  vec3 bt = vec3(b, s + n.y * n.y * a, -n.y);
  return local.x * t + local.y * bt + local.z * n;
}

// The direction at angle theta from axis and azimuth phi, given 1 - cos(theta): near the axis 1 - cos^2 would
// cancel (float resolves cos only to 6e-8 near 1, and a forward lobe's deflections reach 1e-6).
HAZE_INLINE vec3 direction_around(vec3 axis, float one_minus_cos, float phi) {
  float sin_theta = sqrt(max(0.0f, one_minus_cos * (2.0f - one_minus_cos)));
  return onb_to_world(axis, vec3(sin_theta * cos(phi), sin_theta * sin(phi), 1.0f - one_minus_cos));
}

HAZE_INLINE vec3 sample_uniform_sphere(vec2 u) {
  float z = 1.0f - 2.0f * u.x;
  float r = sqrt(max(0.0f, 1.0f - z * z));
  float phi = 2.0f * PI * u.y;
  return vec3(r * cos(phi), r * sin(phi), z);
}

// Cosine-weighted direction around n; pdf = cos(theta) / pi.
HAZE_INLINE vec3 sample_cosine_hemisphere(vec3 n, vec2 u) {
  float r = sqrt(u.x);
  float phi = 2.0f * PI * u.y;
  return onb_to_world(n, vec3(r * cos(phi), r * sin(phi), sqrt(max(0.0f, 1.0f - u.x))));
}

// Uniform direction in the cone of half-angle acos(cos_max) around axis; pdf = 1 / (2 pi (1 - cos_max)).
HAZE_INLINE vec3 sample_uniform_cone(vec3 axis, float cos_max, vec2 u) {
  return direction_around(axis, u.x * (1.0f - cos_max), 2.0f * PI * u.y);
}

// Henyey-Greenstein phase function. mu is the cosine of the deflection angle between the incoming and
// outgoing travel directions (mu = 1: forward scattering). Normalised over the sphere.
HAZE_INLINE float hg_phase(float mu, float g) {
  float denom = 1.0f + g * g - 2.0f * g * mu;
  return INV_4PI * (1.0f - g * g) / (denom * sqrt(max(denom, 1e-12f)));
}

// Inverse CDF of HG as 1 - mu. With d = 1 - g + 2 g u and s = (1 - g^2) / d, mu = (1 + g^2 - s^2) / 2g, so
// 1 - mu = (1 - g)(1 - u)(s + 1 - g) / d: a product of positive terms, where the quotient's difference of
// squares lost the narrowest deflections in float (at g = 0.99 the sampled lobe came out measurably wide).
// The pdf of the returned direction is hg_phase(mu, g).
HAZE_INLINE float hg_sample_one_minus_mu(float g, float u) {
  if (abs(g) < 1e-3f) return 2.0f * u;
  float d = 1.0f - g + 2.0f * g * u;
  float s = (1.0f - g * g) / d;
  return clamp((1.0f - g) * (1.0f - u) * (s + 1.0f - g) / d, 0.0f, 2.0f);
}

HAZE_INLINE vec3 hg_sample(vec3 travel_dir, float g, vec2 u) {
  return direction_around(travel_dir, hg_sample_one_minus_mu(g, u.x), 2.0f * PI * u.y);
}

// Power heuristic (Veach 1997) of the strategy with density p_a against one with p_b, both over the same
// measure: p_a^2 / (p_a^2 + p_b^2), written with the ratio so that no square overflows; 1 where p_b is 0 (the
// other strategy cannot produce the sample), and an infinite density is taken as the largest float.
HAZE_INLINE float mis_power(float p_a, float p_b) {
  p_a = min(p_a, 3.4e38f);
  p_b = min(p_b, 3.4e38f);
  if (!(p_b > 0.0f)) return 1.0f;
  if (p_a >= p_b) {
    float r = p_b / p_a;
    return 1.0f / (1.0f + r * r);
  }
  float r = p_a / p_b;
  return r * r / (1.0f + r * r);
}

// Equi-angular sampling of t on [t0, t1] along o + t d towards a point c (Kulla and Fajardo 2012).
struct EquiAngular {
  float delta;  // t of the closest approach
  float D;      // distance of c from the ray (kept away from 0)
  float theta_a, theta_b;
};

HAZE_INLINE EquiAngular equi_angular_setup(vec3 o, vec3 d, vec3 c, float t0, float t1) {
  EquiAngular e;
  e.delta = dot(c - o, d);
  e.D = max(length(c - (o + e.delta * d)), 1e-6f * max(1.0f, abs(e.delta)));
  e.theta_a = atan((t0 - e.delta) / e.D);
  e.theta_b = atan((t1 - e.delta) / e.D);
  return e;
}

HAZE_INLINE float equi_angular_sample(EquiAngular e, float u) {
  return e.delta + e.D * tan(mix(e.theta_a, e.theta_b, u));
}

HAZE_INLINE float equi_angular_pdf(EquiAngular e, float t) {
  float x = t - e.delta;
  return e.D / (max(e.theta_b - e.theta_a, 1e-20f) * (e.D * e.D + x * x));
}

// The part [a, b] of [t0, t1] of the line o + t d (d unit) inside the cone with apex p, unit axis `axis` and
// cos_outer c: dot(x - p, axis) >= c |x - p| (a spot light's cone, c >= 0 up to rounding; c < -1: no cone,
// [t0, t1] itself). The cone is convex, so the part is one interval; a >= b when the line misses it. From
// f(t) = (wa + t da)^2 - c^2 |w + t d|^2 >= 0 (the double cone) on the half-line wa + t da >= 0 (its front).
HAZE_INLINE vec2 cone_clip(vec3 o, vec3 d, vec3 p, vec3 axis, float c, float t0, float t1) {
  if (c < -1.0f) return vec2(t0, t1);
  c = max(c, 0.0f);
  vec3 w = o - p;
  float wa = dot(w, axis), da = dot(d, axis);
  float c2 = c * c;
  float A = da * da - c2;
  float B = 2.0f * (wa * da - c2 * dot(w, d));
  float C = wa * wa - c2 * dot(w, w);
  // The front half-line [h0, h1].
  float h0 = -T_INF, h1 = T_INF;
  if (da > 0.0f)
    h0 = -wa / da;
  else if (da < 0.0f)
    h1 = -wa / da;
  else if (wa < 0.0f)
    return vec2(1.0f, 0.0f);
  float a = -T_INF, b = T_INF;
  float disc = B * B - 4.0f * A * C;
  if (abs(A) < 1e-7f * c2 + 1e-30f) {
    // Parallel to the cone's surface: f is linear, B t + C >= 0.
    if (B > 0.0f)
      a = -C / B;
    else if (B < 0.0f)
      b = -C / B;
    else if (C < 0.0f)
      return vec2(1.0f, 0.0f);
  } else if (disc < 0.0f) {
    if (A < 0.0f) return vec2(1.0f, 0.0f);  // f < 0 everywhere
  } else {
    float q = -0.5f * (B + (B >= 0.0f ? sqrt(disc) : -sqrt(disc)));
    float r1 = q != 0.0f ? C / q : 0.0f, r2 = q / A;
    float lo = min(r1, r2), hi = max(r1, r2);
    if (A < 0.0f) {
      a = lo;  // between the roots
      b = hi;
    } else if (da > 0.0f) {
      a = hi;  // the front nappe is the far piece
    } else {
      b = lo;
    }
  }
  return vec2(max(max(a, h0), t0), min(min(b, h1), t1));
}

// Exponential in optical depth truncated to [0, tau_total]: the majorant free-flight distribution
// restricted to a segment, so no sample is wasted beyond it.
HAZE_INLINE float truncated_exp_sample_tau(float tau_total, float u) {
  return -log_one_minus(u * one_minus_exp_neg(tau_total));
}

// Density in tau of the above; multiply by sigma_maj(t) for the density in t.
HAZE_INLINE float truncated_exp_pdf_tau(float tau, float tau_total) {
  return exp(-tau) / max(one_minus_exp_neg(tau_total), 1e-30f);
}

// Complementary error function (Numerical Recipes' erfcc: relative error below 1.2e-7 everywhere); GLSL
// has no erf.
HAZE_INLINE float erfc_approx(float x) {
  float z = abs(x);
  float t = 1.0f / (1.0f + 0.5f * z);
  float r =
      t * exp(-z * z - 1.26551223f +
              t * (1.00002368f +
                   t * (0.37409196f +
                        t * (0.09678418f +
                             t * (-0.18628806f +
                                  t * (0.27886807f +
                                       t * (-1.13520398f +
                                            t * (1.48851587f + t * (-0.82215223f + t * 0.17087277f)))))))));
  return x >= 0.0f ? r : 2.0f - r;
}

// Standard normal CDF, accurate in relative terms in the lower tail.
HAZE_INLINE float normal_cdf(float x) {
  return 0.5f * erfc_approx(-x * 0.70710678118654752f);
}

// Inverse of normal_cdf for p in (0, 1) (Acklam's rational approximation, relative error 1.2e-9 before
// float rounding).
HAZE_INLINE float normal_cdf_inverse(float p) {
  p = clamp(p, 1e-37f, 1.0f - 6e-8f);
  const float p_low = 0.02425f;
  if (p < p_low || p > 1.0f - p_low) {
    float q = sqrt(-2.0f * log(p < p_low ? p : 1.0f - p));
    float x = (((((-7.784894002430293e-03f * q - 3.223964580411365e-01f) * q - 2.400758277161838e+00f) * q -
                 2.549732539343734e+00f) *
                    q +
                4.374664141464968e+00f) *
                   q +
               2.938163982698783e+00f) /
              ((((7.784695709041462e-03f * q + 3.224671290700398e-01f) * q + 2.445134137142996e+00f) * q +
                3.754408661907416e+00f) *
                   q +
               1.0f);
    return p < p_low ? x : -x;
  }
  float q = p - 0.5f;
  float r = q * q;
  return (((((-3.969683028665376e+01f * r + 2.209460984245205e+02f) * r - 2.759285104469687e+02f) * r +
            1.383577518672690e+02f) *
               r -
           3.066479806614716e+01f) *
              r +
          2.506628277459239e+00f) *
         q /
         (((((-5.447609879822406e+01f * r + 1.615858368580409e+02f) * r - 1.556989798598866e+02f) * r +
            6.680131188771972e+01f) *
               r -
           1.328068155288572e+01f) *
              r +
          1.0f);
}

// A Gaussian N(mu, sigma) truncated to [t0, t1] and renormalised: no sample falls outside, none is lost.
// Intervals right of the mean are mirrored so that the CDF differences are taken in the lower tail, where
// they keep their relative precision. Where the interval holds less than 1e-30 of the Gaussian (or sigma
// is not positive) the distribution is uniform on [t0, t1] instead; sampler and pdf agree on that choice.
struct TruncatedGaussian {
  float mu, sigma, t0, t1;
  bool mirrored;  // the standardised interval [a, b] is [-(t1 - mu), -(t0 - mu)] / sigma
  float a, b;     // standardised bounds after mirroring
  float cdf_a;    // normal_cdf(a)
  float mass;     // normal_cdf(b) - normal_cdf(a); 0: uniform fallback
};

HAZE_INLINE TruncatedGaussian truncated_gaussian(float mu, float sigma, float t0, float t1) {
  TruncatedGaussian g;
  g.mu = mu;
  g.sigma = sigma;
  g.t0 = t0;
  g.t1 = t1;
  g.mass = 0.0f;
  g.a = 0.0f;
  g.b = 0.0f;
  g.cdf_a = 0.0f;
  g.mirrored = false;
  if (!(sigma > 0.0f) || !(t1 > t0)) return g;
  float a = (t0 - mu) / sigma, b = (t1 - mu) / sigma;
  g.mirrored = a + b > 0.0f;
  g.a = g.mirrored ? -b : a;
  g.b = g.mirrored ? -a : b;
  g.cdf_a = normal_cdf(g.a);
  float m = normal_cdf(g.b) - g.cdf_a;
  g.mass = m > 1e-30f ? m : 0.0f;
  return g;
}

HAZE_INLINE float truncated_gaussian_sample(TruncatedGaussian g, float u) {
  if (g.mass == 0.0f) return mix(g.t0, g.t1, u);
  float x = normal_cdf_inverse(g.cdf_a + u * g.mass);
  x = clamp(x, g.a, g.b);
  return clamp(g.mu + g.sigma * (g.mirrored ? -x : x), g.t0, g.t1);
}

HAZE_INLINE float truncated_gaussian_pdf(TruncatedGaussian g, float t) {
  if (!(t >= g.t0 && t <= g.t1)) return 0.0f;
  if (g.mass == 0.0f) return g.t1 > g.t0 ? 1.0f / (g.t1 - g.t0) : 0.0f;
  float x = (t - g.mu) / g.sigma;
  return 0.39894228040143268f * exp(-0.5f * x * x) / (g.sigma * g.mass);
}

#endif
