#pragma once
// World-space triangles of mesh instances, and the binary BVH over them that the shaders traverse
// (shaders/surfaces/bvh.glsl). Embree's rtcBuildBVH builds it with our node and leaf callbacks; the host
// flattens the tree into GpuBvhNode/GpuTriangle arrays.

#include <cstdint>
#include <glm/glm.hpp>
#include <span>
#include <string>
#include <vector>

#include "gpu/buffer.hpp"
#include "gpu/kernel.hpp"
#include "surfaces/bvh_layout.hpp"
#include "surfaces/mesh.hpp"

namespace haze::gpu {
class Context;
}

namespace haze::surfaces {

// One placement of a mesh; its instance id is its index in the instance list.
struct Instance {
  uint32_t mesh = 0;                // index into the mesh list
  glm::mat4 object_to_world{1.0f};  // affine and invertible
};

// Every instance's triangles in world space, instance by instance and by primitive id within each. The w
// components carry the ids (GpuTriangle): v0.w primitive, v1.w instance, v2.w the index in this list.
// Mirroring transforms get their winding reversed (as append() does). Throws Error for a mesh index out of
// range, a transform that is not finite, affine and invertible, vertices that overflow float, or more
// than 2^32 - 2 triangles.
std::vector<glsl::GpuTriangle> world_triangles(std::span<const Mesh> meshes,
                                               std::span<const Instance> instances);

struct BvhOptions {
  uint32_t max_leaf_size = 4;      // triangles per leaf, 1..32
  float traversal_cost = 1.0f;     // SAH cost of one node visit ...
  float intersection_cost = 1.0f;  // ... and of one triangle test
};

struct Bvh {
  std::vector<glsl::GpuBvhNode> nodes;       // root first; the children of a node are adjacent
  std::vector<glsl::GpuTriangle> triangles;  // leaf order, each input triangle exactly once
  uint32_t depth = 0;                        // levels, a lone root leaf = 1
  uint32_t leaves = 0;
};

// SAH build (RTC_BUILD_QUALITY_HIGH, binned SAH; no spatial splits, so no triangle is referenced twice),
// flattened. An empty input gives one empty leaf that every ray misses. Throws Error on bad options, on
// an Embree failure, or when the tree is deeper than the shader's stack allows (BVH_STACK_SIZE + 1).
Bvh build_bvh(std::span<const glsl::GpuTriangle> triangles, const BvhOptions& options = {});

// The ids packed into a triangle's w components.
inline uint32_t primitive_id(const glsl::GpuTriangle& t) {
  return glm::floatBitsToUint(t.v0.w);
}
inline uint32_t instance_id(const glsl::GpuTriangle& t) {
  return glm::floatBitsToUint(t.v1.w);
}
inline uint32_t input_index(const glsl::GpuTriangle& t) {
  return glm::floatBitsToUint(t.v2.w);
}

// The BVH's two storage buffers (memory ledger category "scene data"), bound as the shaders' bvh_nodes
// and bvh_triangles (shaders/surfaces/bvh.glsl).
struct DeviceBvh : gpu::DeviceData {
  gpu::Buffer nodes, triangles;
  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
};
DeviceBvh upload(gpu::Context& ctx, const Bvh& bvh);

// The test and benchmark kernel shaders/surfaces/trace_rays.comp: `rays` GpuRay in the binding "rays", one
// GpuRayHit each out in "hits"; the occlusion query when `any_hit`. Push constant: the ray count.
gpu::KernelDecl trace_rays_decl(const DeviceBvh& bvh, uint64_t rays, bool any_hit);

}  // namespace haze::surfaces
