#pragma once
// Triangle meshes: OBJ files and built-in primitives, in object space.

#include <cstddef>
#include <cstdint>
#include <glm/glm.hpp>
#include <string>
#include <vector>

#include "surfaces/error.hpp"

namespace haze::surfaces {

// Every component finite (vertices with NaN or Inf are dropped with their triangles, and counted).
inline bool finite(glm::vec3 v) {
  return !glm::any(glm::isnan(v)) && !glm::any(glm::isinf(v));
}

// Indexed triangles, counter-clockwise seen from the side the normals point to.
struct Mesh {
  std::vector<glm::vec3> positions;
  std::vector<glm::vec3> normals;     // per vertex; empty when the source has none
  std::vector<glm::vec2> uvs;         // per vertex; empty when the source has none
  std::vector<glm::uvec3> triangles;  // indices into positions (and normals, uvs)
};

// What drop_bad_triangles() kept and dropped.
struct MeshStats {
  size_t triangles = 0;           // kept
  size_t dropped_nonfinite = 0;   // a vertex with a NaN or Inf position or texture coordinate
  size_t dropped_degenerate = 0;  // zero area (repeated or collinear vertices)
  size_t dropped() const { return dropped_nonfinite + dropped_degenerate; }
};

// Removes triangles that no ray can hit meaningfully: non-finite vertices (positions or uvs) and zero area
// (the cross product of two edges, in double precision, is exactly zero). Vertices stay. Throws Error when an
// index is out of range or normals/uvs do not match positions in size.
MeshStats drop_bad_triangles(Mesh& mesh);

// Reads a Wavefront OBJ (polygons are triangulated, materials ignored). Vertices are shared by their
// (position, uv, normal) index triple; normals and uvs are kept only when every face corner has them.
// Bad triangles are dropped as drop_bad_triangles() does and counted in *stats. Throws Error (one line
// naming the file) for a missing file, a malformed OBJ (parse error, face with fewer than 3 vertices,
// index out of range) or no triangles left.
Mesh load_obj(const std::string& path, MeshStats* stats = nullptr);

// Built-in primitives, centred at the origin; the planar ones lie in z = 0 facing +z. Parameters are
// checked (Error names the primitive and the parameter).

// Rectangle of size.x by size.y, two triangles, uvs over [0, 1]^2.
Mesh plane(glm::vec2 size);
// Axis-aligned box, 12 triangles facing outwards, a vertex per face corner (flat normals).
Mesh box(glm::vec3 size);
// UV sphere with poles on the y axis: `segments` (>= 3) slices and max(2, segments / 2) stacks, a fan at
// each pole so that no triangle is degenerate. Seam and pole vertices are duplicated for the uvs with
// bitwise equal positions, so the surface stays watertight.
Mesh sphere(float radius, uint32_t segments);
// A window with Venetian blinds: a rectangular frame of bar width `frame` (0: none) around the opening,
// and `slats` horizontal slats filling it. Each slat is a box spanning the opening's width, with chord
// opening height / slats and thickness `slat_thickness`, turned about its long (x) axis by
// `slat_angle_deg`: 0 = horizontal (fully open), +-90 = in the window plane (closed, adjacent slats touch).
// The frame's depth is max(frame, chord), so open slats stay inside it.
Mesh window(float width, float height, float frame, uint32_t slats, float slat_thickness,
            float slat_angle_deg);
// A single-sided panel with holes_x by holes_y square holes of side hole_size, one centred in each cell of
// a regular grid. Vertices are shared, so the panel is watertight between holes.
Mesh perforated_panel(float width, float height, uint32_t holes_x, uint32_t holes_y, float hole_size);

// Whether an affine transform mirrors (negative determinant): its triangles then get their winding, v1 and
// v2, swapped so that the front stays the normals' side.
inline bool mirrors(const glm::mat4& transform) {
  return glm::determinant(glm::mat3(transform)) < 0;
}

// Appends src transformed by `transform` (affine, invertible) to dst; normals use the inverse transpose, and
// a mirroring transform has its triangles' winding reversed so the front stays the normals' side. dst keeps
// normals/uvs only when both meshes have them (or dst was empty).
void append(Mesh& dst, const Mesh& src, const glm::mat4& transform = glm::mat4(1.0f));

// Sum of triangle areas (double precision).
double surface_area(const Mesh& mesh);

}  // namespace haze::surfaces
