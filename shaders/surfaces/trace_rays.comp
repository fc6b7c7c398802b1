#version 460
// Test and benchmark kernel: one ray per invocation through the surfaces BVH. ANY_HIT (specialization
// constant 0) turns the closest-hit query into the occlusion query (hits[i].t_uv.w = 1 when occluded).
#extension GL_GOOGLE_include_directive : require

layout(local_size_x = 64) in;
#include "common/dispatch.glsl"
layout(constant_id = 0) const uint ANY_HIT = 0u;

#include "surfaces/bvh_layout.glsl"

layout(std430, binding = BINDING_rays) readonly buffer Rays {
  GpuRay rays[];
};
layout(std430, binding = BINDING_hits) writeonly buffer Hits {
  GpuRayHit hits[];
};

layout(push_constant) uniform Push {
  uint count;
}
pc;

#include "surfaces/bvh.glsl"

void main() {
  uint i = invocation_index();
  if (i >= pc.count) return;
  GpuRay ray = rays[i];
  GpuRayHit out_hit;
  if (ANY_HIT != 0u) {
    bool occluded =
        bvh_occluded(ray.origin_tmin.xyz, ray.direction_tmax.xyz, ray.origin_tmin.w, ray.direction_tmax.w);
    out_hit.t_uv = vec4(ray.direction_tmax.w, 0.0, 0.0, occluded ? 1.0 : 0.0);
    out_hit.normal = vec4(0.0);
    out_hit.ids = uvec4(BVH_NONE);
  } else {
    BvhHit h =
        bvh_closest_hit(ray.origin_tmin.xyz, ray.direction_tmax.xyz, ray.origin_tmin.w, ray.direction_tmax.w);
    bool hit = h.triangle != BVH_NONE;
    uint index = hit ? floatBitsToUint(bvh_triangles[h.triangle].v2.w) : BVH_NONE;
    out_hit.t_uv = vec4(h.t, h.uv, hit ? 1.0 : 0.0);
    out_hit.normal = vec4(h.normal, 0.0);
    out_hit.ids = uvec4(h.triangle, h.instance, h.primitive, index);
  }
  hits[i] = out_hit;
}
