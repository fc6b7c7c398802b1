// Which compile-time shader variant a scene needs: a feature the scene does not use adds no shader code
// (lavapipe executes both sides of even a uniform branch) and no buffer.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <string>

#include "scene/scene.hpp"

namespace haze::volume {

// Bit order = the FEATURES list of trace.comp in shaders/CMakeLists.txt.
struct Features {
  bool hetero = false;    // VDB media: NanoVDB + majorant grid
  bool haze = false;      // homogeneous haze
  bool emission = false;  // an emitting VDB medium
  bool sun = false;
  bool env = false;
  bool local = false;     // point or spot lights: equi-angular sampling
  bool multi = false;     // max_depth > 1
  bool surfaces = false;  // triangle meshes: BVH, instances
  bool area = false;      // emissive surfaces (lights for NEE)
  bool texture = false;   // albedo textures: per-triangle uvs, texels
  bool guiding = false;   // distance guiding (guiding.enabled, media and lights present)

  uint32_t mask() const {
    return uint32_t(hetero) | uint32_t(haze) << 1 | uint32_t(emission) << 2 | uint32_t(sun) << 3 |
           uint32_t(env) << 4 | uint32_t(local) << 5 | uint32_t(multi) << 6 | uint32_t(surfaces) << 7 |
           uint32_t(area) << 8 | uint32_t(texture) << 9 | uint32_t(guiding) << 10;
  }
  // The G-buffer pass's variant (shaders/surfaces/gbuffer.comp: SURFACES TEXTURE).
  uint32_t gbuffer_mask() const { return uint32_t(surfaces) | uint32_t(texture) << 1; }
  bool lights() const { return sun || env || local || area; }
  std::string describe() const;
};

Features features_of(const scene::Scene& s);

// Vertices across and down the distance-guiding grid (GpuScene::guide_grid.xy).
glm::uvec2 guide_grid_size(const scene::Scene& s);

}  // namespace haze::volume
