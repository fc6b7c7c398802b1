#version 460
// The light sampler and the densities of lights/lights.glsl, for the tests to compare with the map's own
// density and the light table (tests/lights_test.cpp). One invocation per item, three vec4 out each:
// mode 0 draws sample_light() at points[i % point_count] with random numbers from (seed, i):
//   (wi, dist), (Li, chosen light), (pdf, environment_pdf(wi), triangle_pdf of the chosen light, 0);
// mode 1 evaluates at the direction points[i]: (background, environment_pdf), (light_choice_pmf(i) for
//   i < the light count), 0.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;
#include "common/color.glsl"
#include "common/compat.glsl"
#include "common/dispatch.glsl"
#include "common/rng.glsl"
#include "common/sampling.glsl"
#include "volume/gpu_scene.glsl"
layout(std430, binding = BINDING_points) readonly buffer Points {
  vec4 points[];
};
layout(std430, binding = BINDING_samples) writeonly buffer Samples {
  vec4 samples[];
};
layout(push_constant) uniform Push {
  uint count;
  uint point_count;
  uint seed;
  uint mode;
}
pc;
#include "lights/lights.glsl"

void main() {
  uint i = invocation_index();
  if (i >= pc.count) return;
  vec4 a = vec4(0.0f), b = vec4(0.0f), c = vec4(0.0f);
  if (pc.mode == 0u) {
#if HAZE_LIGHTS
    uint rng = rng_init(pc.seed, i, 0u);
    vec3 u = vec3(rng_next(rng), rng_next(rng), rng_next(rng));
    LightSample s = sample_light(points[i % pc.point_count].xyz, u);
    a = vec4(s.wi, s.dist);
    b = vec4(s.Li, float(s.light));
    c.x = s.pdf;
#if HAZE_ENV
    c.y = environment_pdf(s.wi);
#endif
#if HAZE_AREA
    if (uint(lights[s.light].position.w) == LIGHT_TRIANGLE) c.z = triangle_pdf(s.light, s.wi, s.dist);
#endif
#endif
  } else {
    vec3 d = points[i].xyz;
    a.xyz = background(d);
#if HAZE_ENV
    a.w = environment_pdf(d);
#endif
#if HAZE_LIGHTS
    if (i < scene.counts.y) b.x = light_choice_pmf(i);
#endif
  }
  samples[3u * i] = a;
  samples[3u * i + 1u] = b;
  samples[3u * i + 2u] = c;
}
