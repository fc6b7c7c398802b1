#include "volume/device_scene.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <glm/gtc/matrix_transform.hpp>

namespace haze::volume {

std::string Features::describe() const {
  std::string s;
  auto add = [&](bool on, const char* name) {
    if (!on) return;
    if (!s.empty()) s += "+";
    s += name;
  };
  add(hetero, "hetero");
  add(haze, "haze");
  add(emission, "emission");
  add(sun, "sun");
  add(env, "env");
  add(local, "local");
  add(multi, "multi");
  add(surfaces, "surfaces");
  add(area, "area");
  add(texture, "texture");
  add(guiding, "guiding");
  return s.empty() ? "empty" : s;
}

glm::uvec2 guide_grid_size(const scene::Scene& s) {
  // Vertex i sits at pixel coordinate i * spacing; one more column and row cover the far edge.
  uint32_t S = uint32_t(std::max(s.guiding.spacing, 1));
  return {uint32_t(s.render.width) / S + 2, uint32_t(s.render.height) / S + 2};
}

Features features_of(const scene::Scene& s) {
  Features f;
  f.hetero = !s.media.empty();
  f.haze = s.haze.has_value() && s.haze->sigma_t > 0.f;
  f.emission = std::any_of(s.media.begin(), s.media.end(),
                           [](const scene::Medium& m) { return m.emission.mode != "none"; });
  f.sun = s.lights.sun.has_value();
  f.env = s.lights.environment.has_value();
  f.local = !s.lights.points.empty() || !s.lights.spots.empty();
  f.multi = s.render.max_depth > 1;
  f.surfaces = !s.surfaces.empty();
  f.area = std::any_of(s.surfaces.begin(), s.surfaces.end(), [](const scene::Surface& m) {
    return glm::any(glm::greaterThan(m.emission, glm::vec3(0)));
  });
  f.texture = std::any_of(s.surfaces.begin(), s.surfaces.end(),
                          [](const scene::Surface& m) { return !m.albedo_texture.empty(); });
  // Guiding learns where light scatters towards the camera: it needs a medium and a light.
  f.guiding = s.guiding.enabled && (f.hetero || f.haze) && f.lights();
  return f;
}

namespace {

float clamp_g(float g, const std::string& where, std::vector<std::string>& notes) {
  float c = std::clamp(g, -kMaxAbsG, kMaxAbsG);
  if (c != g) notes.push_back(fmt::format("{}: g clamped from {} to {}", where, g, c));
  return c;
}

uint32_t append_grid(DeviceMedia& dm, vdb::DeviceGrid&& g) {
  // PNanoVDB addresses are byte offsets into one uint array; NanoVDB grids need 32-byte alignment.
  size_t offset = dm.nanovdb.size() * 4;
  offset = (offset + 31) & ~size_t(31);
  size_t words = (offset + g.nanovdb.size() + 3) / 4;
  dm.nanovdb.resize(words, 0u);
  std::memcpy(reinterpret_cast<uint8_t*>(dm.nanovdb.data()) + offset, g.nanovdb.data(), g.nanovdb.size());
  dm.nan_voxels += g.nan_voxels;
  dm.grids.push_back(std::move(g));
  return uint32_t(offset);
}

std::string resolve_path(const scene::Scene& s, const std::string& file) {
  std::filesystem::path p(file);
  if (p.is_relative() && !s.base_dir.empty()) p = std::filesystem::path(s.base_dir) / p;
  return p.string();
}

}  // namespace

namespace {

// Returns the grid `source` from `previous`, else makes it.
template <class Make>
vdb::DeviceGrid grid_for(const std::string& source, const DeviceMedia* previous, Make&& make) {
  if (previous)
    for (size_t i = 0; i < previous->grid_sources.size(); ++i)
      if (previous->grid_sources[i] == source) return previous->grids[i];
  return make();
}

}  // namespace

DeviceMedia build_media(const scene::Scene& s, const DeviceMedia* previous) {
  DeviceMedia dm;
  std::vector<vdb::MajorantInput> maj_in;
  std::vector<glm::dmat4> object_to_world;
  std::vector<size_t> density_index;  // into dm.grids
  for (size_t i = 0; i < s.media.size(); ++i) {
    const scene::Medium& m = s.media[i];
    std::string where = fmt::format("media[{}]", i);
    std::string source =
        m.procedural ? "procedural " + m.procedural->dump() : resolve_path(s, m.file) + " " + m.grid;
    vdb::DeviceGrid density = grid_for(source, previous, [&] {
      return m.procedural
                 ? vdb::make_procedural(vdb::procedural_from_json(*m.procedural, where + ".procedural"))
                 : vdb::load_grid(resolve_path(s, m.file), m.grid);
    });
    if (density.nan_voxels > 0)
      dm.notes.push_back(fmt::format("{}: {} NaN/Inf voxels replaced by 0", where, density.nan_voxels));
    glsl::GpuMedium g{};
    glm::dmat4 o2w = glm::dmat4(m.transform.matrix());
    glm::dmat4 i2w = o2w * density.index_to_world;
    g.world_to_index = glm::mat4(glm::inverse(i2w));
    g.albedo_g = glm::vec4(m.albedo, clamp_g(m.g, where, dm.notes));
    // World bounds of the index bbox dilated by one voxel (the trilinear support).
    glm::dvec3 lo(1e300), hi(-1e300);
    for (int c = 0; c < 8; ++c) {
      glm::dvec3 ip((c & 1) ? density.index_max.x + 1 : density.index_min.x - 1,
                    (c & 2) ? density.index_max.y + 1 : density.index_min.y - 1,
                    (c & 4) ? density.index_max.z + 1 : density.index_min.z - 1);
      glm::dvec3 w = glm::dvec3(i2w * glm::dvec4(ip, 1.0));
      lo = glm::min(lo, w);
      hi = glm::max(hi, w);
    }
    g.world_min = glm::vec4(glm::vec3(lo), m.density_scale);
    g.world_max = glm::vec4(glm::vec3(hi), m.emission.scale);
    uint32_t mode = m.emission.mode == "scale" ? 1u : m.emission.mode == "blackbody" ? 2u : 0u;
    g.emission = glm::vec4(m.emission.temperature_scale, 0, 0, 0);
    dm.media.push_back(g);
    object_to_world.push_back(o2w);

    uint32_t emission_offset = 0;
    bool separate_emission = mode != 0 && !m.procedural && m.emission.grid != m.grid;
    density_index.push_back(dm.grids.size());
    dm.grid_sources.push_back(source);
    uint32_t density_offset = append_grid(dm, std::move(density));
    if (mode != 0) {
      if (separate_emission) {
        std::string e_source = resolve_path(s, m.file) + " " + m.emission.grid;
        vdb::DeviceGrid e = grid_for(
            e_source, previous, [&] { return vdb::load_grid(resolve_path(s, m.file), m.emission.grid); });
        dm.grid_sources.push_back(e_source);
        // The emission grid is read with the density grid's index transform: they must share it.
        if (e.index_to_world != dm.grids[density_index.back()].index_to_world)
          throw vdb::Error(
              fmt::format("{}: grid '{}' and grid '{}' of {} have different transforms; resample the "
                          "emission grid onto the density grid",
                          where, m.emission.grid, m.grid, m.file));
        emission_offset = append_grid(dm, std::move(e));
      } else {
        emission_offset = density_offset;  // procedural media emit in proportion to their density
      }
    }
    dm.media.back().grid = glm::uvec4(density_offset, emission_offset, mode, 0);
  }
  // Majorant inputs point into dm.grids, which no longer reallocates.
  for (size_t i = 0; i < s.media.size(); ++i)
    maj_in.push_back({&dm.grids[density_index[i]], object_to_world[i], double(s.media[i].density_scale)});
  dm.majorant = vdb::build_majorant(maj_in, s.render.majorant_resolution);
  return dm;
}

std::vector<glsl::GpuLight> build_lights(const scene::Scene& s) {
  std::vector<glsl::GpuLight> out;
  for (const auto& p : s.lights.points) {
    glsl::GpuLight l{};
    l.position = glm::vec4(p.position, float(glsl::LIGHT_POINT));
    l.radiance = glm::vec4(p.color * p.intensity, 0);
    l.direction = glm::vec4(0, -1, 0, 0);
    l.params = glm::vec4(-2.f, -1.5f, 0, 0);  // no falloff anywhere on the sphere
    out.push_back(l);
  }
  for (const auto& sp : s.lights.spots) {
    glsl::GpuLight l{};
    l.position = glm::vec4(sp.position, float(glsl::LIGHT_POINT));
    l.radiance = glm::vec4(sp.color * sp.intensity, 0);
    l.direction = glm::vec4(glm::normalize(sp.direction), 0);
    float cos_outer = std::cos(glm::radians(sp.cone_angle));
    float cos_inner = std::cos(glm::radians(std::max(sp.cone_angle - sp.falloff_angle, 0.f)));
    l.params = glm::vec4(cos_outer, std::max(cos_inner, cos_outer + 1e-6f), 0, 0);
    out.push_back(l);
  }
  if (s.lights.sun) {
    const auto& sun = *s.lights.sun;
    glsl::GpuLight l{};
    l.position = glm::vec4(0, 0, 0, float(glsl::LIGHT_SUN));
    l.radiance = glm::vec4(sun.color * sun.irradiance, 0);
    l.direction = glm::vec4(glm::normalize(sun.direction), 0);
    l.params = glm::vec4(std::cos(glm::radians(sun.angular_diameter * 0.5f)), 0, 0, 0);
    out.push_back(l);
  }
  if (s.lights.environment) {
    glsl::GpuLight l{};
    l.position = glm::vec4(0, 0, 0, float(glsl::LIGHT_ENV));
    l.radiance = glm::vec4(s.lights.environment->color * s.lights.environment->intensity, 0);
    out.push_back(l);
  }
  return out;
}

CameraBasis camera_basis(const scene::Camera& c, const scene::RenderSettings& r) {
  glm::vec3 fwd = glm::normalize(c.target - c.position);
  glm::vec3 right = glm::normalize(glm::cross(fwd, c.up));
  glm::vec3 up = glm::cross(right, fwd);
  float tan_half = std::tan(glm::radians(c.fov_y) * 0.5f);
  float aspect = float(r.width) / float(r.height);
  return {glm::vec4(c.position, 0), glm::vec4(right * tan_half * aspect, 0), glm::vec4(up * tan_half, 0),
          glm::vec4(fwd, 0)};
}

glsl::GpuScene build_gpu_scene(const scene::Scene& s, const DeviceMedia& dm, size_t num_lights,
                               size_t num_local_lights, uint32_t frame, const scene::Camera* prev_camera) {
  glsl::GpuScene g{};
  CameraBasis cb = camera_basis(s.camera, s.render);
  g.cam_position = cb.position;
  g.cam_right = cb.right;
  g.cam_up = cb.up;
  g.cam_forward = cb.forward;
  CameraBasis pb = camera_basis(prev_camera ? *prev_camera : s.camera, s.render);
  g.prev_cam_position = pb.position;
  g.prev_cam_right = pb.right;
  g.prev_cam_up = pb.up;
  g.prev_cam_forward = pb.forward;
  g.counts2 = glm::uvec4(s.surfaces.size(), 0, 0, 0);
  g.size = glm::uvec4(s.render.width, s.render.height, s.render.volume_samples, s.render.max_depth);
  g.counts = glm::uvec4(dm.media.size(), num_lights, num_local_lights, s.render.seed ^ (frame * 0x9e3779b9u));
  if (s.haze) {
    const auto& h = *s.haze;
    g.haze_albedo_g = glm::vec4(h.albedo, std::clamp(h.g, -kMaxAbsG, kMaxAbsG));
    glm::vec3 lo = h.bounded ? h.bounds_min : glm::vec3(-glsl::T_INF);
    glm::vec3 hi = h.bounded ? h.bounds_max : glm::vec3(glsl::T_INF);
    g.haze_min = glm::vec4(lo, h.sigma_t);
    g.haze_max = glm::vec4(hi, 0);
  }
  if (s.lights.environment)
    g.env = glm::vec4(s.lights.environment->color * s.lights.environment->intensity, 0);
  g.sun_direction = glm::vec4(0, 1, 0, 1);  // cos 1: no visible disk
  if (s.lights.sun && s.lights.sun->angular_diameter > 0.f) {
    const auto& sun = *s.lights.sun;
    float cos_max = std::cos(glm::radians(sun.angular_diameter * 0.5f));
    float omega = 2.f * glsl::PI * (1.f - cos_max);
    g.sun_direction = glm::vec4(glm::normalize(sun.direction), cos_max);
    g.sun_radiance = glm::vec4(sun.color * sun.irradiance / std::max(omega, 1e-30f), 0);
  }
  g.maj_res = glm::uvec4(glm::max(dm.majorant.res, glm::ivec3(0)), kMaxTrackingSteps);
  g.maj_min = glm::vec4(dm.majorant.world_min, 0);
  g.maj_max = glm::vec4(dm.majorant.world_max, 0);
  g.settings = glm::vec4(s.render.equiangular_probability, s.render.rr_threshold,
                         s.render.pixel_jitter ? 1.f : 0.f, 0);
  const auto& gp = s.guiding;
  g.guide = glm::vec4(gp.probability, gp.min_width, gp.prior_width, gp.prior_count);
  g.guide_grid = glm::uvec4(guide_grid_size(s), gp.states, gp.candidates);
  g.guide_learn = glm::vec4(float(gp.spacing), gp.learn ? 1.f : 0.f, float(gp.max_count), gp.min_alpha);
  return g;
}

}  // namespace haze::volume
