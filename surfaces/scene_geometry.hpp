// The surfaces of a scene: meshes (built-in primitives or OBJ files), their instances and the BVH over all
// of them in world space, plus what the renderer needs for materials, emitters and motion.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "scene/scene.hpp"
#include "surfaces/bvh.hpp"
#include "surfaces/mesh.hpp"
#include "surfaces/texture.hpp"

namespace haze::surfaces {

// A built-in primitive from its JSON spec {"kind": ..., parameters}; unknown keys and bad values name
// `where` and the key.
Mesh mesh_from_json(const nlohmann::json& spec, const std::string& where);

struct EmissiveTriangle {
  glm::vec3 v0, v1, v2;
  glm::vec3 radiance;
};

struct SceneGeometry {
  std::vector<Mesh> meshes;          // one per scene surface
  std::vector<std::string> sources;  // what each mesh was made from, for reuse across frames
  std::vector<Instance> instances;   // one per scene surface, same order
  Bvh bvh;
  std::vector<EmissiveTriangle> emitters;  // the emissive instances' triangles, in instance order
  // Per instance, the index in `emitters` of its first triangle (its triangle p is emitters[first + p]);
  // 0 for an instance that does not emit.
  std::vector<uint32_t> instance_first_emitter;
  // Albedo textures, each file once; instance_texture[i] indexes them (-1: none).
  std::vector<Texture> textures;
  std::vector<std::string> texture_paths;
  std::vector<int32_t> instance_texture;
  // Corner uvs of bvh.triangles (same order), only when a surface is textured.
  std::vector<glsl::GpuTriangleUv> triangle_uvs;
  // Corner shading normals of bvh.triangles (same order), only when a mesh has smooth vertex normals (OBJ
  // vn, the sphere primitive): vertex normals that differ from their triangles' geometric normals.
  std::vector<glsl::GpuTriangleNormals> triangle_normals;
  std::vector<std::string> notes;  // dropped triangles and the like
};

// The texels of all textures for the shaders' texel buffer (pack_texels, one texture after another), and
// each texture's uvec4 {first texel, width, height, 1} for GpuInstance::texture.
std::vector<glm::uvec2> packed_texels(const SceneGeometry& g, std::vector<glm::uvec4>* placement);

// Whether a mesh has vertex normals that differ from its triangles' geometric normals (a flat mesh's normals
// add nothing to shading).
bool smooth_normals(const Mesh& m);

// Meshes of `previous` whose source is unchanged are reused (an animation only moves them).
SceneGeometry build_geometry(const scene::Scene& s, const SceneGeometry* previous = nullptr);

}  // namespace haze::surfaces
