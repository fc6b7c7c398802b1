// Light sampling for next-event estimation and the radiance seen by rays that leave the scene. The
// kernel declares the binding "lights" when the scene has any, and "env_texels", "env_conditional" and
// "env_marginal" for an environment map (lights/lights.hpp); without a map, background() reads only the
// scene block.
//
// For multiple importance sampling, every density a light sampler uses can be evaluated for a given
// direction: light_choice_pmf(l) (the probability of picking entry l), environment_pdf(wi) and
// triangle_pdf(l, x, wi) (solid angle, the choice not included); LightSample.pdf is their product for the
// sampled direction.
#ifndef HAZE_LIGHTS_GLSL
#define HAZE_LIGHTS_GLSL

#include "lights/light_layout.glsl"

#if HAZE_SUN || HAZE_ENV || HAZE_LOCAL || HAZE_AREA
#define HAZE_LIGHTS 1
layout(std430, binding = BINDING_lights) readonly buffer LightBuffer {
  GpuLight lights[];
};
#endif

#if HAZE_ENV_MAP
// The map (lights/environment.hpp): RGB radiance per pixel, rows from the top; per row the fixed-point CDF
// at each pixel's right edge; the CDF over rows at each row's lower edge.
layout(std430, binding = BINDING_env_texels) readonly buffer EnvTexels {
  float env_texels[];
};
layout(std430, binding = BINDING_env_conditional) readonly buffer EnvConditional {
  float env_conditional[];
};
layout(std430, binding = BINDING_env_marginal) readonly buffer EnvMarginal {
  float env_marginal[];
};

// The environment is the light list's last entry: radiance.rgb the intensity, direction.xy the cosine and
// sine of the map's turn about +y, params.xy its width and height.
GpuLight environment_light() {
  return lights[scene.counts.y - 1u];
}

// Map coordinates (u, v) in [0, 1]^2 of a world direction: turned back by the map's rotation, then
// theta = pi v from +y and phi = 2 pi u with the image centre towards -z.
vec2 environment_uv(GpuLight e, vec3 d) {
  float c = e.direction.x, s = e.direction.y;
  vec3 l = vec3(c * d.x - s * d.z, d.y, s * d.x + c * d.z);
  float phi = atan(-l.x, l.z);
  if (phi < 0.0f) phi += 2.0f * PI;
  return vec2(phi * (0.5f * INV_PI), acos(clamp(l.y, -1.0f, 1.0f)) * INV_PI);
}

uvec2 environment_pixel(GpuLight e, vec2 uv) {
  uvec2 size = uvec2(e.params.xy);
  return min(uvec2(uv * vec2(size)), size - 1u);
}

// Probability of pixel p under the sampler: the row's share of the marginal times the pixel's of its row.
float environment_pixel_probability(GpuLight e, uvec2 p) {
  uint W = uint(e.params.x);
  float row = env_marginal[p.y] - (p.y > 0u ? env_marginal[p.y - 1u] : 0.0f);
  uint k = p.y * W + p.x;
  float col = env_conditional[k] - (p.x > 0u ? env_conditional[k - 1u] : 0.0f);
  return row * col;
}

// Radiance of the map towards d (nearest pixel), intensity included.
vec3 environment_radiance(vec3 d) {
  GpuLight e = environment_light();
  uvec2 p = environment_pixel(e, environment_uv(e, d));
  uint k = 3u * (p.y * uint(e.params.x) + p.x);
  return e.radiance.rgb * vec3(env_texels[k], env_texels[k + 1u], env_texels[k + 2u]);
}
#endif

#if HAZE_ENV
// Solid-angle density of the environment's sampler at direction wi (the light choice not included):
// p(u, v) / (2 pi^2 sin theta) for a map, 1 / (4 pi) for a constant environment.
float environment_pdf(vec3 wi) {
#if HAZE_ENV_MAP
  GpuLight e = environment_light();
  vec2 uv = environment_uv(e, wi);
  float p = environment_pixel_probability(e, environment_pixel(e, uv)) * e.params.x * e.params.y;
  float sin_theta = sin(PI * uv.y);
  return sin_theta > 0.0f ? p / (2.0f * PI * PI * sin_theta) : 0.0f;
#else
  return INV_4PI;
#endif
}
#endif

#if HAZE_ENV
// The environment's radiance towards d (the sun's disc not included).
vec3 environment_Le(vec3 d) {
#if HAZE_ENV_MAP
  return environment_radiance(d);
#else
  return scene.env.rgb;
#endif
}
#endif

vec3 background(vec3 d) {
  vec3 L = vec3(0.0f);
#if HAZE_ENV
  L = environment_Le(d);
#endif
  if (scene.sun_direction.w < 1.0f && dot(d, scene.sun_direction.xyz) >= scene.sun_direction.w)
    L += scene.sun_radiance.rgb;
  return L;
}

#if HAZE_LIGHTS
struct LightSample {
  vec3 wi;     // towards the light
  float dist;  // T_INF for distant lights
  vec3 Li;     // radiance / pdf, including the choice of one light out of all
  uint light;  // the entry of the light list that was chosen
  float pdf;   // solid-angle density of wi, the choice included; 0 for a point, spot or a sun without disc
};

// Probability that sample_light() picks entry l.
float light_choice_pmf(uint l) {
  return lights[l].radiance.w;
}

// The lights that rays other than shadow rays reach, so that light sampling and phase/BSDF sampling both
// produce their paths: the environment and emissive triangles (MIS weighs the two; the sun, points and
// spots are reached by light sampling alone).
bool light_reached_by_walks(uint l) {
  uint type = uint(lights[l].position.w);
  return type == LIGHT_ENV || type == LIGHT_TRIANGLE;
}

#if HAZE_ENV
// Solid-angle density with which sample_light() produces direction wi towards the environment, the choice
// included.
float environment_light_pdf(vec3 wi) {
  return light_choice_pmf(scene.counts.y - 1u) * environment_pdf(wi);
}
#endif

// The alias table over the light list (lights/lights.hpp, alias_table): with U the 24 random bits of u,
// slot s = floor(U n / 2^24) keeps s when U n mod 2^24 is under its threshold, else takes its alias.
uint light_choose(float u) {
  uint n = scene.counts.y;
  uint U = min(uint(u * 16777216.0f), 16777215u);
  uint hi, lo;
  umulExtended(U, n, hi, lo);
  uint s = min((hi << 8u) | (lo >> 24u), n - 1u);
  return (lo & 0xffffffu) < uint(lights[s].direction.w) ? s : uint(lights[s].params.w);
}

#if HAZE_AREA
// The entry of emissive triangle k (in the surfaces' emitter order, surfaces/scene_geometry.hpp) in the light
// list: the point and spot lights come first.
uint emitter_light(uint k) {
  return scene.counts.z + k;
}

// Solid-angle density at x of sampling light l (an emissive triangle) uniformly in area, for the direction
// wi that reaches it at distance t: t^2 / (A |cos_l|); the choice not included.
float triangle_pdf(uint l, vec3 wi, float t) {
  GpuLight light = lights[l];
  vec3 c = cross(light.direction.xyz - light.position.xyz, light.params.xyz - light.position.xyz);
  float area2 = length(c);
  float cos_l = area2 > 0.0f ? abs(dot(c / area2, wi)) : 0.0f;
  return cos_l > 0.0f ? t * t / (0.5f * area2 * cos_l) : 0.0f;
}
#endif

// One light chosen by light_choose(u.x) (by power, or uniformly: lights.choice); u.yz sample it.
LightSample sample_light(vec3 x, vec3 u) {
  uint l = light_choose(u.x);
  GpuLight light = lights[l];
  uint type = uint(light.position.w);
  LightSample s;
  s.wi = vec3(0.0f, 1.0f, 0.0f);
  s.dist = T_INF;
  s.Li = vec3(0.0f);
  s.light = l;
  s.pdf = 0.0f;
  float pmf = light.radiance.w;
#if HAZE_LOCAL
  if (type == LIGHT_POINT) {
    vec3 to = light.position.xyz - x;
    float r2 = max(dot(to, to), 1e-12f);
    s.dist = sqrt(r2);
    s.wi = to / s.dist;
    float falloff = smoothstep(light.params.x, light.params.y, dot(-s.wi, light.direction.xyz));
    s.Li = light.radiance.rgb * (falloff / r2);
  }
#endif
#if HAZE_SUN
  if (type == LIGHT_SUN) {
    // Uniform over the sun's cone: radiance E / Omega divided by the pdf 1 / Omega.
    float cos_max = light.params.x;
    s.wi = cos_max < 1.0f ? sample_uniform_cone(light.direction.xyz, cos_max, u.yz) : light.direction.xyz;
    s.Li = light.radiance.rgb;
    s.pdf = cos_max < 1.0f ? 1.0f / (2.0f * PI * (1.0f - cos_max)) : 0.0f;
  }
#endif
#if HAZE_AREA
  if (type == LIGHT_TRIANGLE) {
    // Uniform in area, converted to solid angle: Li / pdf = Le A |cos_l| / r^2 (two-sided emitter).
    vec3 v0 = light.position.xyz, v1 = light.direction.xyz, v2 = light.params.xyz;
    float b = sqrt(u.y);
    vec3 p = (1.0f - b) * v0 + b * (1.0f - u.z) * v1 + b * u.z * v2;
    vec3 c = cross(v1 - v0, v2 - v0);
    float area2 = length(c);
    vec3 to = p - x;
    float r2 = max(dot(to, to), 1e-12f);
    s.dist = sqrt(r2);
    s.wi = to / s.dist;
    float cos_l = area2 > 0.0f ? abs(dot(c / area2, s.wi)) : 0.0f;
    s.Li = light.radiance.rgb * (0.5f * area2 * cos_l / r2);
    s.pdf = cos_l > 0.0f ? r2 / (0.5f * area2 * cos_l) : 0.0f;
  }
#endif
#if HAZE_ENV
  if (type == LIGHT_ENV) {
#if HAZE_ENV_MAP
    // A row by the marginal CDF, a pixel of it by its conditional CDF (each the first entry above u), then
    // (u, v) uniformly inside the pixel: density p(u, v) = W H P(pixel) over the unit square.
    uint W = uint(light.params.x), H = uint(light.params.y);
    uint lo = 0u, hi = H - 1u;
    while (lo < hi) {
      uint mid = (lo + hi) >> 1u;
      if (env_marginal[mid] > u.y)
        hi = mid;
      else
        lo = mid + 1u;
    }
    uint j = lo;
    float r0 = j > 0u ? env_marginal[j - 1u] : 0.0f, r1 = env_marginal[j];
    uint row = j * W;
    lo = 0u;
    hi = W - 1u;
    while (lo < hi) {
      uint mid = (lo + hi) >> 1u;
      if (env_conditional[row + mid] > u.z)
        hi = mid;
      else
        lo = mid + 1u;
    }
    uint i = lo;
    float c0 = i > 0u ? env_conditional[row + i - 1u] : 0.0f, c1 = env_conditional[row + i];
    vec2 uv = vec2((float(i) + clamp((u.z - c0) / (c1 - c0), 0.0f, 1.0f)) / float(W),
                   (float(j) + clamp((u.y - r0) / (r1 - r0), 0.0f, 1.0f)) / float(H));
    float theta = PI * uv.y, phi = 2.0f * PI * uv.x;
    float sin_theta = sin(theta);
    vec3 d = vec3(-sin(phi) * sin_theta, cos(theta), cos(phi) * sin_theta);
    float cr = light.direction.x, sr = light.direction.y;
    s.wi = vec3(cr * d.x + sr * d.z, d.y, -sr * d.x + cr * d.z);
    float p = (r1 - r0) * (c1 - c0) * float(W * H);
    uint k = 3u * (row + i);
    vec3 L = light.radiance.rgb * vec3(env_texels[k], env_texels[k + 1u], env_texels[k + 2u]);
    // L / pdf with pdf = p / (2 pi^2 sin theta): a pixel at a pole (sin theta = 0) has no solid angle.
    s.Li = L * (2.0f * PI * PI * sin_theta / p);
    s.pdf = sin_theta > 0.0f ? p / (2.0f * PI * PI * sin_theta) : 0.0f;
#else
    s.wi = sample_uniform_sphere(u.yz);
    s.Li = light.radiance.rgb * (4.0f * PI);
    s.pdf = INV_4PI;
#endif
  }
#endif
  s.Li = pmf > 0.0f ? s.Li / pmf : vec3(0.0f);
  s.pdf *= pmf;
  return s;
}
#endif

#endif
