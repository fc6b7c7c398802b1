#include "surfaces/device_surfaces.hpp"

#include <fmt/format.h>

#include <algorithm>

namespace haze::surfaces {

void DeviceSurfaces::update(const scene::Scene& s, const scene::Scene& p) {
  geometry_ = build_geometry(s, &geometry_);
  textured_ = std::any_of(s.surfaces.begin(), s.surfaces.end(),
                          [](const scene::Surface& m) { return !m.albedo_texture.empty(); });
  const bool on = !s.surfaces.empty();
  gpu::keep_uploaded(ctx_, bvh_.nodes, on, "bvh nodes", "scene data", geometry_.bvh.nodes, "GpuBvhNode");
  gpu::keep_uploaded(ctx_, bvh_.triangles, on, "bvh triangles", "scene data", geometry_.bvh.triangles,
                     "GpuTriangle");
  std::vector<glm::uvec4> placement;
  std::vector<glm::uvec2> texels = packed_texels(geometry_, &placement);
  std::vector<glsl::GpuInstance> inst;
  for (size_t i = 0; i < s.surfaces.size(); ++i) {
    glsl::GpuInstance g{};
    if (geometry_.instance_texture[i] >= 0) g.texture = placement[size_t(geometry_.instance_texture[i])];
    g.albedo = glm::vec4(s.surfaces[i].albedo, 0);
    g.emission = glm::vec4(s.surfaces[i].emission, glm::uintBitsToFloat(geometry_.instance_first_emitter[i]));
    glm::mat4 now = s.surfaces[i].transform.matrix();
    glm::mat4 before = i < p.surfaces.size() ? p.surfaces[i].transform.matrix() : now;
    g.world_to_prev_world = glm::mat4(glm::dmat4(before) * glm::inverse(glm::dmat4(now)));
    inst.push_back(g);
  }
  gpu::keep_uploaded(ctx_, instances_, on, "instances", "scene data", inst, "GpuInstance");
  gpu::keep_uploaded(ctx_, uvs_, on && textured_, "triangle uvs", "scene data", geometry_.triangle_uvs,
                     "GpuTriangleUv");
  gpu::keep_uploaded(ctx_, texels_, on && textured_, "albedo textures", "scene data", texels,
                     fmt::format("RGB unorm16, {} textures", placement.size()));
  gpu::keep_uploaded(ctx_, normals_, on && smooth(), "triangle normals", "scene data",
                     geometry_.triangle_normals, "3 x octahedral snorm16x2 + flag per triangle");
}

void DeviceSurfaces::declare(gpu::KernelDecl& k) const {
  if (!any()) return;
  k.define("HAZE_SURFACES");
  if (textured_) k.define("HAZE_TEXTURE");
  if (smooth()) k.define("HAZE_NORMALS");
  bvh_.declare(k);
  k.buffer("instances", instances_.size(), sizeof(glsl::GpuInstance));
  if (textured_) {
    k.buffer("bvh_uvs", uvs_.size(), sizeof(glsl::GpuTriangleUv));
    k.buffer("texels", texels_.size(), 8);
  }
  if (smooth()) k.buffer("bvh_normals", normals_.size(), sizeof(glsl::GpuTriangleNormals));
}

void DeviceSurfaces::bind(gpu::Bindings& b) const {
  if (!any()) return;
  bvh_.bind(b);
  b.set("instances", instances_);
  if (textured_) {
    b.set("bvh_uvs", uvs_);
    b.set("texels", texels_);
  }
  if (smooth()) b.set("bvh_normals", normals_);
}

void DeviceSurfaces::fill(glsl::GpuScene& g) const {
  g.counts2.x = uint32_t(geometry_.instances.size());
}

}  // namespace haze::surfaces
