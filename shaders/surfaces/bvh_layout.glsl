// The flattened BVH, the instance table and the ray/hit records of the test kernel, shared with the host
// (surfaces/bvh_layout.hpp includes this with GLM). Only vec4/uvec4 members: std430 and C++ then have the
// same layout. Integers stored in a vec4's w are bit patterns (floatBitsToUint / glm::uintBitsToFloat).
#ifndef HAZE_BVH_LAYOUT_GLSL
#define HAZE_BVH_LAYOUT_GLSL

// bmax_count.w of an internal node; a leaf holds its triangle count there (0 only in an empty BVH's root).
const uint BVH_INTERNAL = 0xffffffffu;
// "No triangle" in hits.
const uint BVH_NONE = 0xffffffffu;
// Traversal stack entries. The host refuses BVHs deeper than this (a node at depth d leaves at most d - 1
// entries on the stack), so the shader never drops a subtree.
const uint BVH_STACK_SIZE = 32u;

// Binary BVH, 32 bytes a node. The two children of an internal node are adjacent: left and left + 1.
// The root is node 0.
struct GpuBvhNode {
  vec4 bmin_left_or_first;  // xyz: box min; w: left child (internal) or first triangle (leaf)
  vec4 bmax_count;          // xyz: box max; w: triangle count (leaf) or BVH_INTERNAL
};

// World-space triangle in leaf order.
struct GpuTriangle {
  vec4 v0;  // w: primitive id (triangle index within its mesh)
  vec4 v1;  // w: instance id
  vec4 v2;  // w: index in the input (world_triangles) order
};

// Per surface instance: its material and where its points were in the previous frame.
struct GpuInstance {
  vec4 albedo;               // rgb Lambertian reflectance
  vec4 emission;             // rgb emitted radiance; w (bits): index of its first triangle among the emitters
  mat4 world_to_prev_world;  // previous object_to_world * inverse(current object_to_world)
  uvec4 texture;  // albedo texture: x first texel in the texel buffer, y width, z height; w 1 if any
};

// Texture coordinates of the corners of the GpuTriangle with the same index (textured scenes only).
struct GpuTriangleUv {
  vec4 uv01;  // xy: v0's uv, zw: v1's
  vec4 uv2;   // xy: v2's uv
};

// Shading normals of the GpuTriangle with the same index (scenes with a smooth mesh only): the corners'
// world-space vertex normals, octahedral (common/packing.glsl) in packSnorm2x16; w 1 when the triangle has
// them, 0 for a flat mesh's triangle or one whose vertex normals are unusable (it shades with its geometric
// normal).
struct GpuTriangleNormals {
  uvec4 n012;  // x, y, z: corners v0, v1, v2; w: 1 if set
};

// Test/benchmark kernel records (shaders/surfaces/trace_rays.comp).
struct GpuRay {
  vec4 origin_tmin;
  vec4 direction_tmax;
};

struct GpuRayHit {
  vec4 t_uv;    // x: t (tmax on a miss), yz: barycentrics u, v; w: 1 when hit
  vec4 normal;  // xyz: unit geometric normal, normalize(cross(v1 - v0, v2 - v0))
  uvec4 ids;    // x: triangle (leaf order) or BVH_NONE, y: instance, z: primitive, w: input order index
};

#endif
