// Built-in primitives (declared in surfaces/mesh.hpp).
#include <fmt/format.h>

#include <cmath>
#include <glm/gtc/constants.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "surfaces/mesh.hpp"

namespace haze::surfaces {
namespace {

// `ok` is written so that NaN parameters fail it.
void require(bool ok, const char* primitive, const std::string& what) {
  if (!ok) throw Error(fmt::format("{}: {}", primitive, what));
}

// Quad centre +- du +- dv, counter-clockwise seen from cross(du, dv).
void add_quad(Mesh& m, glm::vec3 centre, glm::vec3 du, glm::vec3 dv) {
  const uint32_t b = uint32_t(m.positions.size());
  const glm::vec3 n = glm::normalize(glm::cross(du, dv));
  const glm::vec3 p[4] = {centre - du - dv, centre + du - dv, centre + du + dv, centre - du + dv};
  const glm::vec2 uv[4] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  for (int i = 0; i < 4; ++i) {
    m.positions.push_back(p[i]);
    m.normals.push_back(n);
    m.uvs.push_back(uv[i]);
  }
  m.triangles.emplace_back(b, b + 1, b + 2);
  m.triangles.emplace_back(b, b + 2, b + 3);
}

}  // namespace

Mesh plane(glm::vec2 size) {
  require(size.x > 0 && size.y > 0 && std::isfinite(size.x) && std::isfinite(size.y), "plane",
          fmt::format("size ({}, {}) must be positive and finite", size.x, size.y));
  Mesh m;
  add_quad(m, glm::vec3(0), glm::vec3(0.5f * size.x, 0, 0), glm::vec3(0, 0.5f * size.y, 0));
  return m;
}

Mesh box(glm::vec3 size) {
  require(glm::all(glm::greaterThan(size, glm::vec3(0))) && std::isfinite(size.x) && std::isfinite(size.y) &&
              std::isfinite(size.z),
          "box", fmt::format("size ({}, {}, {}) must be positive and finite", size.x, size.y, size.z));
  Mesh m;
  const glm::vec3 h = 0.5f * size;
  for (int a = 0; a < 3; ++a) {
    // u x v = +axis a; the -a face swaps them so that every face looks outwards.
    glm::vec3 n(0), u(0), v(0);
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    n[a] = h[a];
    u[b] = h[b];
    v[c] = h[c];
    add_quad(m, n, u, v);
    add_quad(m, -n, v, u);
  }
  return m;
}

Mesh sphere(float radius, uint32_t segments) {
  require(radius > 0 && std::isfinite(radius), "sphere",
          fmt::format("radius {} must be positive and finite", radius));
  require(segments >= 3 && segments <= 65536, "sphere",
          fmt::format("segments {} must be in [3, 65536]", segments));
  const uint32_t stacks = std::max(2u, segments / 2), cols = segments + 1;
  Mesh m;
  auto add = [&](glm::vec3 n, glm::vec2 uv) {
    m.positions.push_back(radius * n);
    m.normals.push_back(n);
    m.uvs.push_back(uv);
  };
  // Rings 1..stacks-1, cols vertices each; the last column repeats the first column's position exactly.
  for (uint32_t i = 1; i < stacks; ++i) {
    const double theta = glm::pi<double>() * i / stacks;
    for (uint32_t j = 0; j < cols; ++j) {
      const double phi = 2 * glm::pi<double>() * (j % segments) / segments;
      add(glm::vec3(std::sin(theta) * std::cos(phi), std::cos(theta), -std::sin(theta) * std::sin(phi)),
          glm::vec2(float(j) / segments, float(i) / stacks));
    }
  }
  auto ring = [&](uint32_t i, uint32_t j) { return (i - 1) * cols + j; };
  const uint32_t north = uint32_t(m.positions.size());
  for (uint32_t j = 0; j < segments; ++j) add(glm::vec3(0, 1, 0), glm::vec2((j + 0.5f) / segments, 0));
  const uint32_t south = uint32_t(m.positions.size());
  for (uint32_t j = 0; j < segments; ++j) add(glm::vec3(0, -1, 0), glm::vec2((j + 0.5f) / segments, 1));
  for (uint32_t j = 0; j < segments; ++j) {
    m.triangles.emplace_back(north + j, ring(1, j), ring(1, j + 1));
    for (uint32_t i = 1; i + 1 < stacks; ++i) {
      const uint32_t a = ring(i, j), b = ring(i + 1, j), c = ring(i + 1, j + 1), d = ring(i, j + 1);
      m.triangles.emplace_back(a, b, c);
      m.triangles.emplace_back(a, c, d);
    }
    m.triangles.emplace_back(ring(stacks - 1, j), south + j, ring(stacks - 1, j + 1));
  }
  return m;
}

Mesh window(float width, float height, float frame, uint32_t slats, float slat_thickness,
            float slat_angle_deg) {
  require(width > 0 && height > 0 && std::isfinite(width) && std::isfinite(height), "window",
          fmt::format("width {} and height {} must be positive and finite", width, height));
  require(frame >= 0 && 2 * frame < std::min(width, height), "window",
          fmt::format("frame {} must be in [0, min(width, height) / 2 = {})", frame,
                      0.5f * std::min(width, height)));
  require(slats <= 10000, "window", fmt::format("slats {} must be at most 10000", slats));
  require(frame > 0 || slats > 0, "window", "no geometry: frame is 0 and there are no slats");
  const float opening_w = width - 2 * frame, opening_h = height - 2 * frame;
  const float chord = slats ? opening_h / float(slats) : 0.0f;
  if (slats) {
    require(
        slat_thickness > 0 && slat_thickness <= chord, "window",
        fmt::format("slat_thickness {} must be in (0, opening height / slats = {}]", slat_thickness, chord));
    require(slat_angle_deg >= -90 && slat_angle_deg <= 90, "window",
            fmt::format("slat_angle_deg {} must be in [-90, 90]", slat_angle_deg));
  }
  Mesh m;
  const Mesh unit = box(glm::vec3(1));
  auto add_box = [&](glm::vec3 centre, glm::vec3 size, float angle_rad) {
    glm::mat4 t = glm::translate(glm::mat4(1), centre);
    t = glm::rotate(t, angle_rad, glm::vec3(1, 0, 0));
    append(m, unit, glm::scale(t, size));
  };
  if (frame > 0) {
    const float depth = std::max(frame, chord);
    const float bar_y = 0.5f * (height - frame), bar_x = 0.5f * (width - frame);
    add_box({0, bar_y, 0}, {width, frame, depth}, 0);
    add_box({0, -bar_y, 0}, {width, frame, depth}, 0);
    add_box({-bar_x, 0, 0}, {frame, opening_h, depth}, 0);
    add_box({bar_x, 0, 0}, {frame, opening_h, depth}, 0);
  }
  for (uint32_t k = 0; k < slats; ++k) {
    const float y = -0.5f * opening_h + (float(k) + 0.5f) * chord;
    add_box({0, y, 0}, {opening_w, slat_thickness, chord}, glm::radians(slat_angle_deg));
  }
  return m;
}

Mesh perforated_panel(float width, float height, uint32_t holes_x, uint32_t holes_y, float hole_size) {
  require(width > 0 && height > 0 && std::isfinite(width) && std::isfinite(height), "perforated_panel",
          fmt::format("width {} and height {} must be positive and finite", width, height));
  require(holes_x >= 1 && holes_y >= 1 && holes_x <= 4096 && holes_y <= 4096, "perforated_panel",
          fmt::format("holes_x {} and holes_y {} must be in [1, 4096]", holes_x, holes_y));
  const float cell_w = width / float(holes_x), cell_h = height / float(holes_y);
  require(hole_size > 0 && hole_size < std::min(cell_w, cell_h), "perforated_panel",
          fmt::format("hole_size {} must be in (0, cell size {})", hole_size, std::min(cell_w, cell_h)));
  // Grid lines: each cell contributes its left edge and the hole's two edges; the panel's far edge closes.
  auto lines = [&](float extent, uint32_t cells, float cell) {
    std::vector<float> v;
    for (uint32_t i = 0; i < cells; ++i) {
      const float x0 = -0.5f * extent + float(i) * cell;
      v.insert(v.end(), {x0, x0 + 0.5f * (cell - hole_size), x0 + 0.5f * (cell + hole_size)});
    }
    v.push_back(0.5f * extent);
    return v;
  };
  const std::vector<float> xs = lines(width, holes_x, cell_w), ys = lines(height, holes_y, cell_h);
  Mesh m;
  for (float y : ys)
    for (float x : xs) {
      m.positions.emplace_back(x, y, 0.0f);
      m.normals.emplace_back(0, 0, 1);
      m.uvs.emplace_back(x / width + 0.5f, y / height + 0.5f);
    }
  const uint32_t row = uint32_t(xs.size());
  for (uint32_t j = 0; j + 1 < ys.size(); ++j)
    for (uint32_t i = 0; i + 1 < xs.size(); ++i) {
      if (i % 3 == 1 && j % 3 == 1) continue;  // the hole
      const uint32_t a = j * row + i;
      m.triangles.emplace_back(a, a + 1, a + row + 1);
      m.triangles.emplace_back(a, a + row + 1, a + row);
    }
  return m;
}

}  // namespace haze::surfaces
