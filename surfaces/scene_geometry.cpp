#include "surfaces/scene_geometry.hpp"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <glm/gtc/packing.hpp>
#include <set>

#include "shaders/glsl.hpp"
#include "surfaces/error.hpp"

namespace haze::surfaces {

namespace {

// Reads the keys of a primitive spec with defaults; every key must be used.
class SpecReader {
 public:
  SpecReader(const nlohmann::json& j, std::string where) : j_(j), where_(std::move(where)) {}
  float number(const char* key, float def) {
    used_.insert(key);
    auto it = j_.find(key);
    if (it == j_.end()) return def;
    if (!it->is_number()) fail(key, "must be a number, got " + it->dump());
    return it->get<float>();
  }
  uint32_t count(const char* key, uint32_t def) {
    float v = number(key, float(def));
    if (v < 0 || v != std::floor(v)) fail(key, fmt::format("must be a non-negative integer, got {}", v));
    return uint32_t(v);
  }
  glm::vec3 vec(const char* key, glm::vec3 def, int n) {
    used_.insert(key);
    auto it = j_.find(key);
    if (it == j_.end()) return def;
    if (!it->is_array() || int(it->size()) != n)
      fail(key, fmt::format("must be an array of {} numbers, got {}", n, it->dump()));
    glm::vec3 v(0);
    for (int i = 0; i < n; ++i) {
      if (!(*it)[i].is_number()) fail(key, "must hold numbers, got " + it->dump());
      v[i] = (*it)[i].get<float>();
    }
    return v;
  }
  void finish() {
    for (auto it = j_.begin(); it != j_.end(); ++it)
      if (it.key() != "kind" && !used_.count(it.key()))
        fail(it.key(),
             fmt::format("unknown key for a {} mesh; its keys are kind{}{}", j_["kind"].get<std::string>(),
                         used_.empty() ? "" : ", ", fmt::format("{}", fmt::join(used_, ", "))));
  }
  [[noreturn]] void fail(const std::string& key, const std::string& what) const {
    throw Error(fmt::format("{}.{}: {}", where_, key, what));
  }

 private:
  const nlohmann::json& j_;
  std::string where_;
  std::set<std::string> used_;
};

}  // namespace

Mesh mesh_from_json(const nlohmann::json& spec, const std::string& where) {
  if (!spec.is_object() || !spec.contains("kind") || !spec["kind"].is_string())
    throw Error(fmt::format("{}: expected an object with a string \"kind\"", where));
  std::string kind = spec["kind"];
  SpecReader r(spec, where);
  Mesh m;
  if (kind == "plane") {
    glm::vec3 size = r.vec("size", glm::vec3(1, 1, 0), 2);
    r.finish();
    m = plane(glm::vec2(size));
  } else if (kind == "box") {
    glm::vec3 size = r.vec("size", glm::vec3(1), 3);
    r.finish();
    m = box(size);
  } else if (kind == "sphere") {
    float radius = r.number("radius", 0.5f);
    uint32_t segments = r.count("segments", 32);
    r.finish();
    m = sphere(radius, segments);
  } else if (kind == "window") {
    float w = r.number("width", 1), h = r.number("height", 1), frame = r.number("frame", 0.05f);
    uint32_t slats = r.count("slats", 8);
    float thick = r.number("slat_thickness", 0.02f), angle = r.number("slat_angle", 0);
    r.finish();
    m = window(w, h, frame, slats, thick, angle);
  } else if (kind == "perforated_panel") {
    float w = r.number("width", 1), h = r.number("height", 1);
    uint32_t hx = r.count("holes_x", 4), hy = r.count("holes_y", 4);
    float hole = r.number("hole_size", 0.1f);
    r.finish();
    m = perforated_panel(w, h, hx, hy, hole);
  } else {
    r.fail("kind", fmt::format("is '{}'; use one of plane, box, sphere, window, perforated_panel", kind));
  }
  return m;
}

bool smooth_normals(const Mesh& m) {
  if (m.normals.empty()) return false;
  for (glm::uvec3 t : m.triangles) {
    const glm::dvec3 a = m.positions[t.x], b = m.positions[t.y], c = m.positions[t.z];
    const glm::dvec3 ng = glm::normalize(glm::cross(b - a, c - a));
    for (uint32_t i : {t.x, t.y, t.z}) {
      const glm::dvec3 n = m.normals[i];
      const double len = glm::length(n);
      // Unusable normals (zero, non-finite) count as smooth: the triangles that have them are reported.
      if (!(len > 0) || !std::isfinite(len) || glm::dot(n / len, ng) < 1 - 1e-6) return true;
    }
  }
  return false;
}

SceneGeometry build_geometry(const scene::Scene& s, const SceneGeometry* previous) {
  SceneGeometry g;
  for (size_t i = 0; i < s.surfaces.size(); ++i) {
    const scene::Surface& sf = s.surfaces[i];
    std::string where = fmt::format("surfaces[{}]", i);
    std::string source = sf.mesh ? "mesh " + sf.mesh->dump() : "obj " + sf.file;
    const Mesh* reuse = nullptr;
    if (previous)
      for (size_t k = 0; k < previous->sources.size(); ++k)
        if (previous->sources[k] == source) reuse = &previous->meshes[k];
    Mesh m;
    if (reuse) {
      m = *reuse;
    } else if (sf.mesh) {
      m = mesh_from_json(*sf.mesh, where + ".mesh");
    } else {
      MeshStats st;
      m = load_obj(sf.file, &st);
      if (st.dropped() > 0)
        g.notes.push_back(fmt::format("{}: {} dropped {} triangles ({} with NaN/Inf vertices, {} degenerate)",
                                      where, sf.file, st.dropped(), st.dropped_nonfinite,
                                      st.dropped_degenerate));
    }
    int32_t texture = -1;
    if (!sf.albedo_texture.empty()) {
      if (m.uvs.empty())
        throw Error(
            fmt::format("{}.albedo_texture: the mesh ({}) has no texture coordinates; give the OBJ "
                        "vt coordinates or drop the texture",
                        where, sf.mesh ? "built-in" : sf.file));
      auto known = std::find(g.texture_paths.begin(), g.texture_paths.end(), sf.albedo_texture);
      texture = int32_t(known - g.texture_paths.begin());
      if (known == g.texture_paths.end()) {
        const Texture* old = nullptr;
        if (previous)
          for (size_t k = 0; k < previous->texture_paths.size(); ++k)
            if (previous->texture_paths[k] == sf.albedo_texture) old = &previous->textures[k];
        g.textures.push_back(old ? *old : load_texture(sf.albedo_texture));
        g.texture_paths.push_back(sf.albedo_texture);
      }
    }
    g.instance_texture.push_back(texture);
    g.meshes.push_back(std::move(m));
    g.sources.push_back(source);
    g.instances.push_back({uint32_t(i), sf.transform.matrix()});
  }
  std::vector<glsl::GpuTriangle> world = world_triangles(g.meshes, g.instances);
  g.instance_first_emitter.assign(g.instances.size(), 0);
  for (const auto& t : world) {
    uint32_t inst = instance_id(t);
    glm::vec3 e = s.surfaces[inst].emission;
    if (e.x > 0 || e.y > 0 || e.z > 0) {
      // world_triangles() lists an instance's triangles together, in primitive order.
      if (primitive_id(t) == 0) g.instance_first_emitter[inst] = uint32_t(g.emitters.size());
      g.emitters.push_back({glm::vec3(t.v0), glm::vec3(t.v1), glm::vec3(t.v2), e});
    }
  }
  g.bvh = build_bvh(world);
  if (!g.textures.empty()) {
    g.triangle_uvs.resize(g.bvh.triangles.size(), glsl::GpuTriangleUv{});
    for (size_t k = 0; k < g.bvh.triangles.size(); ++k) {
      const glsl::GpuTriangle& t = g.bvh.triangles[k];
      uint32_t inst = instance_id(t);
      if (g.instance_texture[inst] < 0) continue;
      const Mesh& mesh = g.meshes[g.instances[inst].mesh];
      glm::uvec3 c = mesh.triangles[primitive_id(t)];
      // The corner order world_triangles() used: mirroring transforms swap v1 and v2.
      if (mirrors(g.instances[inst].object_to_world)) std::swap(c.y, c.z);
      g.triangle_uvs[k] = {glm::vec4(mesh.uvs[c.x], mesh.uvs[c.y]), glm::vec4(mesh.uvs[c.z], 0, 0)};
    }
  }
  std::vector<bool> smooth(g.meshes.size());
  for (size_t i = 0; i < g.meshes.size(); ++i) smooth[i] = smooth_normals(g.meshes[i]);
  if (std::find(smooth.begin(), smooth.end(), true) != smooth.end()) {
    g.triangle_normals.resize(g.bvh.triangles.size(), glsl::GpuTriangleNormals{});
    std::vector<size_t> unusable(g.instances.size(), 0);
    for (size_t k = 0; k < g.bvh.triangles.size(); ++k) {
      const glsl::GpuTriangle& t = g.bvh.triangles[k];
      const uint32_t inst = instance_id(t);
      const Instance& in = g.instances[inst];
      if (!smooth[in.mesh]) continue;
      const Mesh& mesh = g.meshes[in.mesh];
      glm::uvec3 c = mesh.triangles[primitive_id(t)];
      if (mirrors(in.object_to_world)) std::swap(c.y, c.z);  // world_triangles()'s corner order
      const glm::dmat3 normal_matrix =
          glm::transpose(glm::inverse(glm::dmat3(glm::mat3(in.object_to_world))));
      glm::uvec4 packed(0);
      bool ok = true;
      for (int i = 0; i < 3; ++i) {
        const glm::dvec3 n = normal_matrix * glm::dvec3(mesh.normals[c[i]]);
        const double len = glm::length(n);
        ok = ok && len > 0 && std::isfinite(len);
        if (ok) packed[i] = glm::packSnorm2x16(glsl::oct_encode(glm::vec3(n / len)));
      }
      if (!ok) {
        ++unusable[inst];
        continue;
      }
      packed.w = 1;
      g.triangle_normals[k].n012 = packed;
    }
    for (size_t i = 0; i < unusable.size(); ++i)
      if (unusable[i] > 0)
        g.notes.push_back(fmt::format(
            "surfaces[{}]: {} triangles have a zero or non-finite vertex normal and shade with their "
            "geometric normal",
            i, unusable[i]));
  }
  return g;
}

std::vector<glm::uvec2> packed_texels(const SceneGeometry& g, std::vector<glm::uvec4>* placement) {
  std::vector<glm::uvec2> texels;
  for (const Texture& t : g.textures) {
    placement->emplace_back(uint32_t(texels.size()), t.width, t.height, 1u);
    pack_texels(t, texels);
  }
  return texels;
}

}  // namespace haze::surfaces
