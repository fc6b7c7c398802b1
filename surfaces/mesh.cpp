#include "surfaces/mesh.hpp"

#include <fmt/format.h>
#include <tiny_obj_loader.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <unordered_map>

namespace haze::surfaces {
namespace {

std::string first_line(const std::string& s) {
  std::string line = s.substr(0, s.find('\n'));
  while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
  return line;
}

// An OBJ face corner: position, uv and normal indices (-1: absent).
struct Corner {
  int v, vt, vn;
  bool operator==(const Corner&) const = default;
};
struct CornerHash {
  size_t operator()(const Corner& c) const {
    uint64_t h = uint64_t(uint32_t(c.v)) * 0x9E3779B97F4A7C15ull;
    h ^= (uint64_t(uint32_t(c.vt)) + 0x632BE59BD9B4E019ull + (h << 6) + (h >> 2));
    h ^= (uint64_t(uint32_t(c.vn)) * 0xC2B2AE3D27D4EB4Full + (h << 6) + (h >> 2));
    return size_t(h);
  }
};

// What tinyobjloader reads as 0 or skips without a word. A coordinate that is no number ("banana") and a
// face with fewer than 3 corners (a bare "f") are errors naming the line; a number that is not finite in
// float (nan, inf, 1e39) is recorded, so that its vertex becomes NaN and its triangles are dropped and
// counted like any other non-finite vertex.
struct ObjScan {
  std::vector<size_t> bad_v, bad_vt, bad_vn;  // indices (in file order) of non-finite elements
  size_t v = 0, vt = 0, vn = 0;               // elements seen
};

ObjScan scan_obj(const std::string& path, const std::string& text) {
  ObjScan scan;
  size_t line_no = 0, pos = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    if (end == std::string::npos) end = text.size();
    std::string line = text.substr(pos, end - pos);
    pos = end + 1;
    ++line_no;
    if (size_t hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::istringstream words(line);
    std::string kind;
    if (!(words >> kind)) continue;
    if (kind == "f") {
      int corners = 0;
      for (std::string w; words >> w;) ++corners;
      if (corners < 3)
        throw Error(fmt::format(
            "{}:{}: malformed OBJ: a face with fewer than 3 vertices ({}; fix or re-export the file)", path,
            line_no, corners));
      continue;
    }
    std::vector<size_t>* bad = kind == "v"    ? &scan.bad_v
                               : kind == "vt" ? &scan.bad_vt
                               : kind == "vn" ? &scan.bad_vn
                                              : nullptr;
    if (!bad) continue;
    size_t& count = kind == "v" ? scan.v : kind == "vt" ? scan.vt : scan.vn;
    bool finite_all = true;
    for (std::string w; words >> w;) {
      char* stop = nullptr;
      const double x = std::strtod(w.c_str(), &stop);
      if (stop == w.c_str() || *stop != '\0')
        throw Error(fmt::format(
            "{}:{}: malformed OBJ: '{}' in a '{}' line is not a number (fix or re-export the file)", path,
            line_no, w, kind));
      finite_all &= std::isfinite(x) && std::abs(x) <= double(std::numeric_limits<float>::max());
    }
    if (!finite_all) bad->push_back(count);
    ++count;
  }
  return scan;
}

// Sets the elements `bad` of a flat array of `n`-float elements to NaN.
void poison(std::vector<tinyobj::real_t>& flat, size_t n, const std::vector<size_t>& bad) {
  for (size_t i : bad)
    for (size_t k = 0; k < n && i * n + k < flat.size(); ++k)
      flat[i * n + k] = std::numeric_limits<float>::quiet_NaN();
}

}  // namespace

MeshStats drop_bad_triangles(Mesh& mesh) {
  const size_t n = mesh.positions.size();
  if (!mesh.normals.empty() && mesh.normals.size() != n)
    throw Error(fmt::format("mesh: {} normals for {} positions (give one per position or none)",
                            mesh.normals.size(), n));
  if (!mesh.uvs.empty() && mesh.uvs.size() != n)
    throw Error(
        fmt::format("mesh: {} uvs for {} positions (give one per position or none)", mesh.uvs.size(), n));
  MeshStats stats;
  std::vector<glm::uvec3> kept;
  kept.reserve(mesh.triangles.size());
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    glm::uvec3 t = mesh.triangles[i];
    for (int k = 0; k < 3; ++k)
      if (t[k] >= n) throw Error(fmt::format("mesh: triangle {} refers to vertex {} of {}", i, t[k], n));
    glm::vec3 a = mesh.positions[t.x], b = mesh.positions[t.y], c = mesh.positions[t.z];
    bool uv_ok = mesh.uvs.empty() || (std::isfinite(mesh.uvs[t.x].x) && std::isfinite(mesh.uvs[t.x].y) &&
                                      std::isfinite(mesh.uvs[t.y].x) && std::isfinite(mesh.uvs[t.y].y) &&
                                      std::isfinite(mesh.uvs[t.z].x) && std::isfinite(mesh.uvs[t.z].y));
    if (!finite(a) || !finite(b) || !finite(c) || !uv_ok) {
      ++stats.dropped_nonfinite;
      continue;
    }
    // Double precision: float edges of a valid sliver could cancel to zero, doubles of float inputs
    // cancel only for truly collinear points.
    glm::dvec3 cr = glm::cross(glm::dvec3(b) - glm::dvec3(a), glm::dvec3(c) - glm::dvec3(a));
    if (cr == glm::dvec3(0.0)) {
      ++stats.dropped_degenerate;
      continue;
    }
    kept.push_back(t);
  }
  mesh.triangles = std::move(kept);
  stats.triangles = mesh.triangles.size();
  return stats;
}

Mesh load_obj(const std::string& path, MeshStats* stats) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw Error(fmt::format("{}: no such file (check the path)", path));
  if (!std::filesystem::is_regular_file(path, ec))
    throw Error(fmt::format("{}: not a regular file (give the path of an .obj file)", path));
  std::ifstream file(path, std::ios::binary);
  if (!file) throw Error(fmt::format("{}: cannot be opened (check its permissions)", path));
  std::stringstream text;
  text << file.rdbuf();
  const ObjScan scan = scan_obj(path, text.str());
  std::istringstream in(text.str());

  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> materials;
  std::string warn, err;
  // No material reader: materials are not used, and a missing .mtl must not fail the mesh.
  if (!tinyobj::LoadObj(&attrib, &shapes, &materials, &warn, &err, &in, nullptr, true))
    throw Error(fmt::format("{}: malformed OBJ: {} (fix or re-export the file)", path, first_line(err)));
  if (warn.find("Degenerated face") != std::string::npos)
    throw Error(fmt::format(
        "{}: malformed OBJ: a face with fewer than 3 vertices (fix or re-export the file)", path));

  poison(attrib.vertices, 3, scan.bad_v);
  poison(attrib.texcoords, 2, scan.bad_vt);
  poison(attrib.normals, 3, scan.bad_vn);
  const int nv = int(attrib.vertices.size() / 3), nt = int(attrib.texcoords.size() / 2),
            nn = int(attrib.normals.size() / 3);
  bool has_uv = true, has_normal = true;
  size_t corners = 0;
  for (const auto& shape : shapes) {
    for (const auto& idx : shape.mesh.indices) {
      if (idx.vertex_index < 0 || idx.vertex_index >= nv)
        throw Error(
            fmt::format("{}: malformed OBJ: a face refers to vertex {} but the file has {} (fix or "
                        "re-export the file)",
                        path, idx.vertex_index + 1, nv));
      if (idx.texcoord_index >= nt || idx.normal_index >= nn)
        throw Error(
            fmt::format("{}: malformed OBJ: a face refers to a missing uv or normal (fix or "
                        "re-export the file)",
                        path));
      has_uv &= idx.texcoord_index >= 0;
      has_normal &= idx.normal_index >= 0;
    }
    corners += shape.mesh.indices.size();
  }
  if (corners < 3)
    throw Error(
        fmt::format("{}: no triangles (no faces with 3 or more vertices; export the mesh with faces)", path));

  Mesh mesh;
  std::unordered_map<Corner, uint32_t, CornerHash> vertex_of;
  auto vertex = [&](const tinyobj::index_t& idx) {
    Corner c{idx.vertex_index, has_uv ? idx.texcoord_index : -1, has_normal ? idx.normal_index : -1};
    auto [it, inserted] = vertex_of.try_emplace(c, uint32_t(mesh.positions.size()));
    if (inserted) {
      const float* p = &attrib.vertices[3 * size_t(c.v)];
      mesh.positions.emplace_back(p[0], p[1], p[2]);
      if (has_uv)
        mesh.uvs.emplace_back(attrib.texcoords[2 * size_t(c.vt)], attrib.texcoords[2 * size_t(c.vt) + 1]);
      if (has_normal) {
        const float* q = &attrib.normals[3 * size_t(c.vn)];
        mesh.normals.emplace_back(q[0], q[1], q[2]);
      }
    }
    return it->second;
  };
  for (const auto& shape : shapes) {
    const auto& ix = shape.mesh.indices;  // triangulated: three corners per face
    for (size_t i = 0; i + 2 < ix.size(); i += 3)
      mesh.triangles.emplace_back(vertex(ix[i]), vertex(ix[i + 1]), vertex(ix[i + 2]));
  }

  MeshStats s = drop_bad_triangles(mesh);
  if (s.triangles == 0)
    throw Error(
        fmt::format("{}: no valid triangles: all {} have NaN/Inf vertices or zero area (fix the mesh)", path,
                    s.dropped()));
  if (stats) *stats = s;
  return mesh;
}

void append(Mesh& dst, const Mesh& src, const glm::mat4& transform) {
  const bool first = dst.positions.empty();
  const bool normals = !src.normals.empty() && (first || !dst.normals.empty());
  const bool uvs = !src.uvs.empty() && (first || !dst.uvs.empty());
  if (!normals) dst.normals.clear();
  if (!uvs) dst.uvs.clear();
  const uint32_t base = uint32_t(dst.positions.size());
  const glm::mat3 normal_matrix = glm::transpose(glm::inverse(glm::mat3(transform)));
  for (size_t i = 0; i < src.positions.size(); ++i) {
    dst.positions.push_back(glm::vec3(transform * glm::vec4(src.positions[i], 1.0f)));
    if (normals) dst.normals.push_back(glm::normalize(normal_matrix * src.normals[i]));
    if (uvs) dst.uvs.push_back(src.uvs[i]);
  }
  // A mirroring transform reverses the winding; swapping two corners keeps the front where the normals are.
  const bool mirror = mirrors(transform);
  for (glm::uvec3 t : src.triangles)
    dst.triangles.push_back(mirror ? glm::uvec3(t.x, t.z, t.y) + base : t + base);
}

double surface_area(const Mesh& mesh) {
  double area = 0;
  for (glm::uvec3 t : mesh.triangles) {
    glm::dvec3 a = mesh.positions[t.x], b = mesh.positions[t.y], c = mesh.positions[t.z];
    area += 0.5 * glm::length(glm::cross(b - a, c - a));
  }
  return area;
}

}  // namespace haze::surfaces
