// Surface materials at a BVH hit: Lambertian albedo, constant per instance or times an albedo texture, and
// the shading normal. The kernel declares the binding "instances" and, with HAZE_TEXTURE, "bvh_uvs"
// (per-triangle corner uvs in BVH leaf order) and "texels", with HAZE_NORMALS "bvh_normals" (per-triangle
// corner normals, surfaces/device_surfaces.hpp).
#ifndef HAZE_MATERIAL_GLSL
#define HAZE_MATERIAL_GLSL

#include "common/packing.glsl"
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

#if HAZE_NORMALS
layout(std430, binding = BINDING_bvh_normals) readonly buffer TriangleNormals {
  GpuTriangleNormals bvh_normals[];
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

// The shading normal at hit h on the side of n, the geometric normal turned towards where the ray came from:
// the vertex normals interpolated with the hit's barycentrics where the triangle has them, else n. Ray
// origins are offset along n and light arriving from below n is cut (surface_cosine): shading normals
// change how a surface is lit, not which side of it light reaches.
vec3 surface_normal(BvhHit h, vec3 n) {
#if HAZE_NORMALS
  uvec4 c = bvh_normals[h.triangle].n012;
  if (c.w != 0u) {
    vec3 ns = (1.0f - h.uv.x - h.uv.y) * oct_decode(unpackSnorm2x16(c.x)) +
              h.uv.x * oct_decode(unpackSnorm2x16(c.y)) + h.uv.y * oct_decode(unpackSnorm2x16(c.z));
    float len = length(ns);
    // Opposite corner normals can cancel; the geometric normal is then all there is.
    if (len > 1e-6f) return dot(ns, n) < 0.0f ? -ns / len : ns / len;
  }
#endif
  return n;
}

// cos(ns, wi) for light leaving towards wi (or arriving from it), zero when wi lies below the geometric
// normal n: where the shading normal leans past the geometry (the terminator of a coarse mesh), light must
// not leak through the surface.
float surface_cosine(vec3 n, vec3 ns, vec3 wi) {
  return dot(n, wi) > 0.0f ? max(dot(ns, wi), 0.0f) : 0.0f;
}

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
