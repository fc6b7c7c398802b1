#include "volume/media.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <glm/gtc/matrix_transform.hpp>
#include <limits>

namespace haze::volume {

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

// The device's float box one ulp wider (the majorant must cover every point the shader counts inside).
glm::dvec3 outward(glm::vec4 v, float dir) {
  glm::dvec3 r;
  for (int a = 0; a < 3; ++a) r[a] = std::nextafter(v[a], dir * std::numeric_limits<float>::infinity());
  return r;
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
                 ? vdb::make_procedural(vdb::procedural_from_json(
                       *m.procedural, (s.path.empty() ? "" : s.path + ": ") + where + ".procedural"))
                 : vdb::load_grid(resolve_path(s, m.file), m.grid, vdb::NanPolicy::Zero, where + ".grid");
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
    // A bounded medium is zero outside its box: the same test clips it exactly.
    lo = glm::max(lo, glm::dvec3(m.bounds_min));
    hi = glm::min(hi, glm::dvec3(m.bounds_max));
    if (glm::any(glm::greaterThan(lo, hi)))
      throw vdb::Error(
          fmt::format("{}{}.bounds_min/bounds_max: the box misses the medium (whose world box is "
                      "dilated by a voxel); widen it or move it over the medium",
                      s.path.empty() ? "" : s.path + ": ", where));
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
        vdb::DeviceGrid e = grid_for(e_source, previous, [&] {
          return vdb::load_grid(resolve_path(s, m.file), m.emission.grid, vdb::NanPolicy::Zero,
                                where + ".emission.grid");
        });
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
    maj_in.push_back({&dm.grids[density_index[i]], object_to_world[i], double(s.media[i].density_scale),
                      outward(dm.media[i].world_min, -1), outward(dm.media[i].world_max, 1)});
  dm.majorant = vdb::build_majorant(maj_in, s.render.majorant_resolution);
  return dm;
}

std::vector<glsl::MediumMotion> media_motion(const scene::Scene& s, const scene::Scene& p,
                                             const DeviceMedia& media) {
  std::vector<glsl::MediumMotion> moved;
  for (size_t i = 0; i < s.media.size() && i < p.media.size() && i < media.media.size(); ++i) {
    glm::dmat4 now = s.media[i].transform.matrix(), before = p.media[i].transform.matrix();
    if (now == before) continue;
    glsl::MediumMotion m{};
    glm::dmat4 prev_to_now = now * glm::inverse(before), now_to_prev = before * glm::inverse(now);
    m.prev_world_to_world = glm::mat4(prev_to_now);
    glm::dvec3 lo(1e300), hi(-1e300);
    const glm::dvec3 a(media.media[i].world_min), b(media.media[i].world_max);
    for (int c = 0; c < 8; ++c) {
      glm::dvec3 corner(c & 1 ? b.x : a.x, c & 2 ? b.y : a.y, c & 4 ? b.z : a.z);
      glm::dvec3 q = glm::dvec3(now_to_prev * glm::dvec4(corner, 1));
      lo = glm::min(lo, q);
      hi = glm::max(hi, q);
    }
    m.prev_min = glm::vec4(glm::vec3(lo), 0);
    m.prev_max = glm::vec4(glm::vec3(hi), 0);
    moved.push_back(m);
  }
  return moved;
}

void Media::update(const scene::Scene& s, const scene::Scene& prev) {
  host_ = build_media(s, &host_);
  hetero_ = !s.media.empty();
  haze_ = s.haze.has_value() && s.haze->sigma_t > 0.f;
  haze_params_ = s.haze;
  emission_ = std::any_of(s.media.begin(), s.media.end(),
                          [](const scene::Medium& m) { return m.emission.mode != "none"; });
  gpu::keep_uploaded(ctx_, nanovdb_, hetero_, "nanovdb grids", "scene data", host_.nanovdb, "NanoVDB");
  gpu::keep_uploaded(ctx_, table_, hetero_, "media", "scene data", host_.media, "GpuMedium");
  const auto& maj = host_.majorant;
  gpu::keep_uploaded(ctx_, majorant_, hetero_, "majorant grid", "scene data", maj.sigma_max,
                     fmt::format("f32 {}x{}x{}", maj.res.x, maj.res.y, maj.res.z));
  std::vector<glsl::MediumMotion> moved = media_motion(s, prev, host_);
  moving_ = uint32_t(moved.size());
  gpu::keep_uploaded(ctx_, motion_, !moved.empty(), "media motion", "scene data", moved, "MediumMotion");
}

void Media::declare(gpu::KernelDecl& k) const {
  if (hetero_) k.define("HAZE_HETERO");
  if (haze_) k.define("HAZE_HAZE");
  if (!hetero_) return;
  if (emission_) k.define("HAZE_EMISSION");
  k.buffer("nanovdb", nanovdb_.size(), 4);
  k.buffer("media", table_.size(), sizeof(glsl::GpuMedium));
  k.buffer("majorant", majorant_.size(), 4);
}

void Media::bind(gpu::Bindings& b) const {
  if (!hetero_) return;
  b.set("nanovdb", nanovdb_);
  b.set("media", table_);
  b.set("majorant", majorant_);
}

void Media::fill(glsl::GpuScene& g) const {
  g.counts.x = uint32_t(host_.media.size());
  if (haze_params_) {
    const auto& h = *haze_params_;
    g.haze_albedo_g = glm::vec4(h.albedo, std::clamp(h.g, -kMaxAbsG, kMaxAbsG));
    glm::vec3 lo = h.bounded ? h.bounds_min : glm::vec3(-glsl::T_INF);
    glm::vec3 hi = h.bounded ? h.bounds_max : glm::vec3(glsl::T_INF);
    g.haze_min = glm::vec4(lo, h.sigma_t);
    g.haze_max = glm::vec4(hi, 0);
  }
  g.maj_res = glm::uvec4(glm::max(host_.majorant.res, glm::ivec3(0)), kMaxTrackingSteps);
  g.maj_min = glm::vec4(host_.majorant.world_min, 0);
  g.maj_max = glm::vec4(host_.majorant.world_max, 0);
}

}  // namespace haze::volume
