// Surface materials at a BVH hit: Lambertian albedo, constant per instance or times an albedo texture.
// The kernel declares the binding "instances" and, with HAZE_TEXTURE, "bvh_uvs" (per-triangle corner uvs in
// BVH leaf order) and "texels" (surfaces/device_surfaces.hpp).
#ifndef HAZE_MATERIAL_GLSL
#define HAZE_MATERIAL_GLSL

#include "surfaces/bvh.glsl"

layout(std430, binding = BINDING_instances) readonly buffer InstanceBuffer {
  GpuInstance instances[];
};
#if HAZE_TEXTURE
layout(std430, binding = BINDING_bvh_uvs) readonly buffer TriangleUvs {
  GpuTriangleUv bvh_uvs[];
};
layout(std430, binding = BINDING_texels) readonly buffer Texels {
  uvec2 texels[];
};
#endif

#if HAZE_TEXTURE
// Linear RGB of a texel stored as two packUnorm2x16 words (surfaces/texture.cpp); p wraps around.
vec3 texture_texel(uint first, uvec2 size, ivec2 p) {
  ivec2 s = ivec2(size);
  uvec2 q = uvec2((p % s + s) % s);
  uvec2 w = texels[first + q.y * size.x + q.x];
  return vec3(unpackUnorm2x16(w.x), unpackUnorm2x16(w.y).x);
}

// Bilinear filtering with wrap-around (repeat). v = 0 is the bottom row of the image (OBJ convention),
// texel centres sit at half-integer coordinates.
vec3 texture_bilinear(uvec4 tex, vec2 uv) {
  if (!bvh_finite(vec3(uv, 0.0f))) uv = vec2(0.0f);
  uv = uv - floor(uv);
  vec2 p = vec2(uv.x, 1.0f - uv.y) * vec2(tex.yz) - 0.5f;
  vec2 f = p - floor(p);
  ivec2 i = ivec2(floor(p));
  vec3 a = mix(texture_texel(tex.x, tex.yz, i), texture_texel(tex.x, tex.yz, i + ivec2(1, 0)), f.x);
  vec3 b =
      mix(texture_texel(tex.x, tex.yz, i + ivec2(0, 1)), texture_texel(tex.x, tex.yz, i + ivec2(1, 1)), f.x);
  return mix(a, b, f.y);
}
#endif

vec3 surface_albedo(BvhHit h) {
  GpuInstance inst = instances[h.instance];
  vec3 albedo = inst.albedo.rgb;
#if HAZE_TEXTURE
  if (inst.texture.w != 0u) {
    GpuTriangleUv c = bvh_uvs[h.triangle];
    vec2 uv = (1.0f - h.uv.x - h.uv.y) * c.uv01.xy + h.uv.x * c.uv01.zw + h.uv.y * c.uv2.xy;
    albedo *= texture_bilinear(inst.texture, uv);
  }
#endif
  return albedo;
}

#endif
