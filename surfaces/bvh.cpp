#include "surfaces/bvh.hpp"

#include <embree3/rtcore.h>
#include <fmt/format.h>

#include <cmath>
#include <limits>
#include <memory>
#include <new>

#include "gpu/context.hpp"

namespace haze::surfaces {
namespace {

// Build-time tree in Embree's thread-local memory (freed with the RTCBVH). The callbacks run on several
// threads but each touches only the node it is given.
struct BuildNode {
  bool leaf;
};
struct InnerNode : BuildNode {
  BuildNode* children[2];
  RTCBounds bounds[2];
};
struct LeafNode : BuildNode {
  uint32_t count;
  uint32_t* ids;  // input indices
};

void* create_node(RTCThreadLocalAllocator alloc, unsigned int, void*) {
  auto* n = static_cast<InnerNode*>(rtcThreadLocalAlloc(alloc, sizeof(InnerNode), alignof(InnerNode)));
  n->leaf = false;
  n->children[0] = n->children[1] = nullptr;
  return n;
}

void set_children(void* node, void** children, unsigned int count, void*) {
  auto* n = static_cast<InnerNode*>(node);
  for (unsigned i = 0; i < count && i < 2; ++i) n->children[i] = static_cast<BuildNode*>(children[i]);
}

void set_bounds(void* node, const RTCBounds** bounds, unsigned int count, void*) {
  auto* n = static_cast<InnerNode*>(node);
  for (unsigned i = 0; i < count && i < 2; ++i) n->bounds[i] = *bounds[i];
}

void* create_leaf(RTCThreadLocalAllocator alloc, const RTCBuildPrimitive* prims, size_t count, void*) {
  auto* n = static_cast<LeafNode*>(rtcThreadLocalAlloc(alloc, sizeof(LeafNode), alignof(LeafNode)));
  n->leaf = true;
  n->count = uint32_t(count);
  n->ids = static_cast<uint32_t*>(rtcThreadLocalAlloc(alloc, sizeof(uint32_t) * count, alignof(uint32_t)));
  for (size_t i = 0; i < count; ++i) n->ids[i] = prims[i].primID;
  return n;
}

// x moved towards +-inf by one ulp, and by at least 1e-30 (so the gap survives flushing denormals).
float pad(float x, float towards) {
  float y = std::nextafter(x, towards);
  return std::abs(y - x) >= 1e-30f ? y : x + std::copysign(1e-30f, towards);
}

// Boxes are padded outwards: the shader gives a ray's zero direction components a tiny nonzero value, so
// a ray lying exactly in a face plane of an unpadded box would leave it at t = 0 and miss the triangles
// on that face. Padding is monotone, so child boxes stay inside their parent's.
glsl::GpuBvhNode make_node(glm::vec3 lo, glm::vec3 hi) {
  constexpr float inf = std::numeric_limits<float>::infinity();
  for (int i = 0; i < 3; ++i) {
    lo[i] = pad(lo[i], -inf);
    hi[i] = pad(hi[i], inf);
  }
  return {glsl::vec4(lo, 0.0f), glsl::vec4(hi, glm::uintBitsToFloat(glsl::BVH_INTERNAL))};
}

struct Flattener {
  std::span<const glsl::GpuTriangle> input;
  Bvh& out;

  // Writes the node already placed at `index` (its box is set) and its subtree.
  void visit(const BuildNode* n, uint32_t index, uint32_t depth) {
    out.depth = std::max(out.depth, depth);
    if (n->leaf) {
      const auto* leaf = static_cast<const LeafNode*>(n);
      out.nodes[index].bmin_left_or_first.w = glm::uintBitsToFloat(uint32_t(out.triangles.size()));
      out.nodes[index].bmax_count.w = glm::uintBitsToFloat(leaf->count);
      for (uint32_t i = 0; i < leaf->count; ++i) out.triangles.push_back(input[leaf->ids[i]]);
      ++out.leaves;
      return;
    }
    const auto* inner = static_cast<const InnerNode*>(n);
    if (!inner->children[0] || !inner->children[1])
      throw Error("bvh: Embree built a node with fewer than 2 children");
    const uint32_t left = uint32_t(out.nodes.size());
    out.nodes[index].bmin_left_or_first.w = glm::uintBitsToFloat(left);
    for (int i = 0; i < 2; ++i) {
      const RTCBounds& b = inner->bounds[i];
      out.nodes.push_back(make_node({b.lower_x, b.lower_y, b.lower_z}, {b.upper_x, b.upper_y, b.upper_z}));
    }
    visit(inner->children[0], left, depth + 1);
    visit(inner->children[1], left + 1, depth + 1);
  }
};

struct DeviceDeleter {
  void operator()(RTCDevice d) const { rtcReleaseDevice(d); }
};
struct BvhDeleter {
  void operator()(RTCBVH b) const { rtcReleaseBVH(b); }
};

}  // namespace

std::vector<glsl::GpuTriangle> world_triangles(std::span<const Mesh> meshes,
                                               std::span<const Instance> instances) {
  size_t total = 0;
  for (size_t i = 0; i < instances.size(); ++i) {
    const Instance& inst = instances[i];
    if (inst.mesh >= meshes.size())
      throw Error(
          fmt::format("instance {}: mesh {} does not exist ({} meshes)", i, inst.mesh, meshes.size()));
    const glm::mat4& m = inst.object_to_world;
    bool ok = true;
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) ok &= std::isfinite(m[c][r]);
    if (!ok) throw Error(fmt::format("instance {}: transform has NaN or Inf entries", i));
    if (m[0][3] != 0 || m[1][3] != 0 || m[2][3] != 0 || m[3][3] != 1)
      throw Error(fmt::format("instance {}: transform is not affine (last row must be 0 0 0 1)", i));
    const float det = glm::determinant(glm::mat3(m));
    if (!(std::abs(det) > 0) || !std::isfinite(det))
      throw Error(fmt::format("instance {}: transform is singular (a zero scale?)", i));
    total += meshes[inst.mesh].triangles.size();
  }
  if (total >= glsl::BVH_NONE) throw Error(fmt::format("surfaces: {} triangles, at most 2^32 - 2", total));

  std::vector<glsl::GpuTriangle> out;
  out.reserve(total);
  for (uint32_t i = 0; i < instances.size(); ++i) {
    const Mesh& mesh = meshes[instances[i].mesh];
    const glm::mat4& m = instances[i].object_to_world;
    const bool mirror = mirrors(m);
    for (uint32_t p = 0; p < mesh.triangles.size(); ++p) {
      glm::uvec3 t = mesh.triangles[p];
      if (mirror) std::swap(t.y, t.z);
      for (int k = 0; k < 3; ++k)
        if (t[k] >= mesh.positions.size())
          throw Error(fmt::format("instance {}: triangle {} refers to vertex {} of {}", i, p, t[k],
                                  mesh.positions.size()));
      glm::vec3 v[3];
      for (int k = 0; k < 3; ++k) {
        v[k] = glm::vec3(m * glm::vec4(mesh.positions[t[k]], 1.0f));
        if (!finite(v[k]))
          throw Error(
              fmt::format("instance {}: triangle {} is not finite in world space (NaN input or float "
                          "overflow; drop_bad_triangles() removes NaN/Inf vertices)",
                          i, p));
      }
      const uint32_t index = uint32_t(out.size());
      out.push_back({glsl::vec4(v[0], glm::uintBitsToFloat(p)), glsl::vec4(v[1], glm::uintBitsToFloat(i)),
                     glsl::vec4(v[2], glm::uintBitsToFloat(index))});
    }
  }
  return out;
}

Bvh build_bvh(std::span<const glsl::GpuTriangle> triangles, const BvhOptions& options) {
  if (options.max_leaf_size < 1 || options.max_leaf_size > RTC_BUILD_MAX_PRIMITIVES_PER_LEAF)
    throw Error(fmt::format("bvh: max_leaf_size {} must be in [1, {}]", options.max_leaf_size,
                            int(RTC_BUILD_MAX_PRIMITIVES_PER_LEAF)));
  if (!(options.traversal_cost > 0) || !(options.intersection_cost > 0))
    throw Error("bvh: traversal_cost and intersection_cost must be positive");
  if (triangles.size() >= glsl::BVH_NONE)
    throw Error(fmt::format("bvh: {} triangles, at most 2^32 - 2", triangles.size()));

  Bvh out;
  if (triangles.empty()) {
    glsl::GpuBvhNode root = make_node(glm::vec3(0), glm::vec3(0));
    root.bmax_count.w = glm::uintBitsToFloat(0u);
    out.nodes.push_back(root);
    out.depth = out.leaves = 1;
    return out;
  }

  std::vector<RTCBuildPrimitive> prims(triangles.size());
  glm::vec3 lo(std::numeric_limits<float>::infinity()), hi(-std::numeric_limits<float>::infinity());
  for (size_t i = 0; i < triangles.size(); ++i) {
    const glsl::GpuTriangle& t = triangles[i];
    const glm::vec3 a(t.v0), b(t.v1), c(t.v2);
    if (!finite(a) || !finite(b) || !finite(c)) throw Error(fmt::format("bvh: triangle {} is not finite", i));
    const glm::vec3 tlo = glm::min(a, glm::min(b, c)), thi = glm::max(a, glm::max(b, c));
    prims[i] = {tlo.x, tlo.y, tlo.z, 0u, thi.x, thi.y, thi.z, uint32_t(i)};
    lo = glm::min(lo, tlo);
    hi = glm::max(hi, thi);
  }

  std::unique_ptr<RTCDeviceTy, DeviceDeleter> device(rtcNewDevice(nullptr));
  if (!device)
    throw Error(fmt::format("bvh: rtcNewDevice failed (error {})", int(rtcGetDeviceError(nullptr))));
  std::unique_ptr<RTCBVHTy, BvhDeleter> bvh(rtcNewBVH(device.get()));

  RTCBuildArguments args = rtcDefaultBuildArguments();
  args.buildQuality = RTC_BUILD_QUALITY_HIGH;
  args.maxBranchingFactor = 2;
  args.maxDepth = glsl::BVH_STACK_SIZE;
  args.minLeafSize = 1;
  args.maxLeafSize = options.max_leaf_size;
  args.traversalCost = options.traversal_cost;
  args.intersectionCost = options.intersection_cost;
  args.bvh = bvh.get();
  args.primitives = prims.data();
  args.primitiveCount = prims.size();
  args.primitiveArrayCapacity = prims.size();  // no room for spatial splits: each triangle in one leaf
  args.createNode = create_node;
  args.setNodeChildren = set_children;
  args.setNodeBounds = set_bounds;
  args.createLeaf = create_leaf;
  args.splitPrimitive = nullptr;
  void* root = rtcBuildBVH(&args);
  if (!root)
    throw Error(fmt::format("bvh: Embree's rtcBuildBVH failed (error {}; a tree deeper than {} levels?)",
                            int(rtcGetDeviceError(device.get())), glsl::BVH_STACK_SIZE));

  out.nodes.reserve(2 * triangles.size());
  out.triangles.reserve(triangles.size());
  out.nodes.push_back(make_node(lo, hi));
  Flattener{triangles, out}.visit(static_cast<const BuildNode*>(root), 0, 1);
  if (out.triangles.size() != triangles.size())
    throw Error(
        fmt::format("bvh: leaves hold {} triangles, expected {}", out.triangles.size(), triangles.size()));
  if (out.depth > glsl::BVH_STACK_SIZE + 1)
    throw Error(fmt::format("bvh: {} levels deep, the shader's stack allows {}", out.depth,
                            glsl::BVH_STACK_SIZE + 1));
  return out;
}

DeviceBvh upload(gpu::Context& ctx, const Bvh& bvh) {
  DeviceBvh d;
  d.nodes =
      gpu::Buffer(ctx, "bvh nodes", "scene data", bvh.nodes.size() * sizeof(glsl::GpuBvhNode), "GpuBvhNode");
  d.nodes.upload(bvh.nodes);
  d.triangles = gpu::Buffer(ctx, "bvh triangles", "scene data",
                            bvh.triangles.size() * sizeof(glsl::GpuTriangle), "GpuTriangle");
  d.triangles.upload(bvh.triangles);
  return d;
}

void DeviceBvh::declare(gpu::KernelDecl& k) const {
  k.buffer("bvh_nodes", nodes.size(), sizeof(glsl::GpuBvhNode));
  k.buffer("bvh_triangles", triangles.size(), sizeof(glsl::GpuTriangle));
}

void DeviceBvh::bind(gpu::Bindings& b) const {
  b.set("bvh_nodes", nodes).set("bvh_triangles", triangles);
}

gpu::KernelDecl trace_rays_decl(const DeviceBvh& bvh, uint64_t rays, bool any_hit) {
  gpu::KernelDecl d("surfaces/trace_rays.comp");
  bvh.declare(d);
  d.buffer("rays", rays * sizeof(glsl::GpuRay), sizeof(glsl::GpuRay));
  d.buffer("hits", rays * sizeof(glsl::GpuRayHit), sizeof(glsl::GpuRayHit));
  return std::move(d.push(4).specialize({any_hit ? 1u : 0u}));
}

}  // namespace haze::surfaces
