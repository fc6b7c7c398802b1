// Light sampling for next-event estimation and the radiance seen by rays that leave the scene. The
// kernel declares the binding "lights" when the scene has any (lights/lights.hpp); background() reads
// only the scene block.
#ifndef HAZE_LIGHTS_GLSL
#define HAZE_LIGHTS_GLSL

#include "lights/light_layout.glsl"

#if HAZE_SUN || HAZE_ENV || HAZE_LOCAL || HAZE_AREA
#define HAZE_LIGHTS 1
layout(std430, binding = BINDING_lights) readonly buffer LightBuffer {
  GpuLight lights[];
};
#endif

vec3 background(vec3 d) {
  vec3 L = scene.env.rgb;
  if (scene.sun_direction.w < 1.0f && dot(d, scene.sun_direction.xyz) >= scene.sun_direction.w)
    L += scene.sun_radiance.rgb;
  return L;
}

#if HAZE_LIGHTS
struct LightSample {
  vec3 wi;     // towards the light
  float dist;  // T_INF for distant lights
  vec3 Li;     // radiance / pdf, including the choice of one light out of all
};

// One light chosen uniformly; u.x picks the light, u.yz sample it.
LightSample sample_light(vec3 x, vec3 u) {
  uint n = scene.counts.y;
  uint l = min(uint(u.x * float(n)), n - 1u);
  GpuLight light = lights[l];
  uint type = uint(light.position.w);
  LightSample s;
  s.wi = vec3(0.0f, 1.0f, 0.0f);
  s.dist = T_INF;
  s.Li = vec3(0.0f);
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
  }
#endif
#if HAZE_ENV
  if (type == LIGHT_ENV) {
    s.wi = sample_uniform_sphere(u.yz);
    s.Li = light.radiance.rgb * (4.0f * PI);
  }
#endif
  s.Li *= float(n);
  return s;
}
#endif

#endif
