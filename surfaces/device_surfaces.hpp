// The scene's surfaces on the device: the BVH (nodes, triangles in leaf order), the instance table
// (materials and previous transforms) and, for textured scenes, per-triangle uvs and texels.
#pragma once

#include <vector>

#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "scene/scene.hpp"
#include "shaders/glsl.hpp"
#include "surfaces/bvh.hpp"
#include "surfaces/scene_geometry.hpp"

namespace haze::surfaces {

// Features: HAZE_SURFACES (bindings bvh_nodes, bvh_triangles, instances), HAZE_TEXTURE (bvh_uvs, texels),
// HAZE_NORMALS (bvh_normals: shading normals, when a mesh has smooth vertex normals).
// Emissive surfaces are lights (lights/lights.hpp takes emitters()).
class DeviceSurfaces : public gpu::DeviceData {
 public:
  explicit DeviceSurfaces(gpu::Context& ctx) : ctx_(ctx) {}

  // Builds the geometry of `s` (meshes of unchanged sources reused) and the instance table with each
  // instance's motion since `prev`; buffers are reused when their size is unchanged.
  void update(const scene::Scene& s, const scene::Scene& prev);

  bool any() const { return !geometry_.instances.empty(); }
  bool textured() const { return textured_; }
  bool smooth() const { return !geometry_.triangle_normals.empty(); }
  const SceneGeometry& geometry() const { return geometry_; }

  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
  void fill(glsl::GpuScene& g) const;  // counts2.x: the instances

 private:
  gpu::Context& ctx_;
  SceneGeometry geometry_;
  bool textured_ = false;
  DeviceBvh bvh_;
  gpu::Buffer instances_, uvs_, texels_, normals_;
};

}  // namespace haze::surfaces
