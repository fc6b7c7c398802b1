#include "volume/media.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <glm/gtc/matrix_transform.hpp>
#include <limits>
#include <optional>

namespace haze::volume {

namespace {

float clamp_g(float g, const std::string& where, std::vector<std::string>& notes) {
  float c = std::clamp(g, -kMaxAbsG, kMaxAbsG);
  if (c != g) notes.push_back(fmt::format("{}: g clamped from {} to {}", where, g, c));
  return c;
}

std::string resolve_path(const scene::Scene& s, const std::string& file) {
  std::filesystem::path p(file);
  if (p.is_relative() && !s.base_dir.empty()) p = std::filesystem::path(s.base_dir) / p;
  return p.string();
}

}  // namespace

namespace {

// The index in `set` of the grid made from `source`: one added before, else a copy of `previous`'s, else
// made now.
template <class Make>
uint32_t grid_index(GridSet& set, const std::string& source, const std::string& label,
                    const GridSet* previous, Make&& make) {
  for (size_t i = 0; i < set.grid_sources.size(); ++i)
    if (set.grid_sources[i] == source) return uint32_t(i);
  const vdb::DeviceGrid* old = nullptr;
  if (previous)
    for (size_t i = 0; i < previous->grid_sources.size(); ++i)
      if (previous->grid_sources[i] == source) old = &previous->grids[i];
  set.grids.push_back(old ? *old : make());
  set.grid_sources.push_back(source);
  set.grid_labels.push_back(label);
  return uint32_t(set.grids.size() - 1);
}

// World box of a grid's index bbox dilated by one voxel (its trilinear support) under `i2w`.
void world_box(const vdb::DeviceGrid& g, const glm::dmat4& i2w, glm::dvec3& lo, glm::dvec3& hi) {
  lo = glm::dvec3(1e300);
  hi = glm::dvec3(-1e300);
  for (int c = 0; c < 8; ++c) {
    glm::dvec3 ip((c & 1) ? g.index_max.x + 1 : g.index_min.x - 1,
                  (c & 2) ? g.index_max.y + 1 : g.index_min.y - 1,
                  (c & 4) ? g.index_max.z + 1 : g.index_min.z - 1);
    glm::dvec3 w = glm::dvec3(i2w * glm::dvec4(ip, 1.0));
    lo = glm::min(lo, w);
    hi = glm::max(hi, w);
  }
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
    const uint32_t density_grid = grid_index(dm, source, where + ".grid", previous, [&] {
      return m.procedural
                 ? vdb::make_procedural(vdb::procedural_from_json(
                       *m.procedural, (s.path.empty() ? "" : s.path + ": ") + where + ".procedural"))
                 : vdb::load_grid(resolve_path(s, m.file), m.grid, vdb::NanPolicy::Zero, where + ".grid");
    });
    density_index.push_back(density_grid);
    const vdb::DeviceGrid& density = dm.grids[density_grid];
    if (density.nan_voxels > 0)
      dm.notes.push_back(fmt::format("{}: {} NaN/Inf voxels replaced by 0", where, density.nan_voxels));
    glsl::GpuMedium g{};
    glm::dmat4 o2w = glm::dmat4(m.transform.matrix());
    glm::dmat4 i2w = o2w * density.index_to_world;
    g.world_to_index = glm::mat4(glm::inverse(i2w));
    g.albedo_g = glm::vec4(m.albedo, clamp_g(m.g, where, dm.notes));
    g.sigma_t_color = glm::vec4(m.sigma_t_color, 0);
    glm::dvec3 lo, hi;
    world_box(density, i2w, lo, hi);
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

    uint32_t emission_grid = density_grid;  // procedural media emit in proportion to their density
    if (mode != 0 && !m.procedural && m.emission.grid != m.grid) {
      const std::string e_source = resolve_path(s, m.file) + " " + m.emission.grid;
      emission_grid = grid_index(dm, e_source, where + ".emission.grid", previous, [&] {
        return vdb::load_grid(resolve_path(s, m.file), m.emission.grid, vdb::NanPolicy::Zero,
                              where + ".emission.grid");
      });
      if (uint64_t bad = dm.grids[emission_grid].nan_voxels)
        dm.notes.push_back(fmt::format("{}: {} NaN/Inf voxels of emission grid '{}' replaced by 0", where,
                                       bad, m.emission.grid));
      // The emission grid is read with the density grid's index transform: they must share it.
      if (dm.grids[emission_grid].index_to_world != dm.grids[density_grid].index_to_world)
        throw vdb::Error(
            fmt::format("{}: grid '{}' and grid '{}' of {} have different transforms; resample the "
                        "emission grid onto the density grid",
                        where, m.emission.grid, m.grid, m.file));
    }
    dm.media.back().grid = glm::uvec4(density_grid, emission_grid, mode, 0);
  }
  for (const vdb::DeviceGrid& g : dm.grids) dm.nan_voxels += g.nan_voxels;
  // Majorant inputs point into dm.grids, which no longer grows.
  for (size_t i = 0; i < s.media.size(); ++i)
    maj_in.push_back({&dm.grids[density_index[i]], object_to_world[i], double(s.media[i].density_scale),
                      outward(dm.media[i].world_min, -1), outward(dm.media[i].world_max, 1)});
  dm.majorant = vdb::build_majorant(maj_in, s.render.majorant_resolution);
  if (s.render.estimator != "volpath")
    for (size_t i = 0; i < s.media.size(); ++i)
      if (dm.majorant.value_min[i] < 0)
        dm.notes.push_back(fmt::format(
            "media[{}]: the grid has negative values (down to {}): the default estimator reads densities "
            "trilinearly (8 voxels a lookup), not one voxel chosen by the trilinear weights",
            i, dm.majorant.value_min[i]));
  return dm;
}

DeviceVelocity build_velocity(const scene::Scene& prev, const DeviceVelocity* previous) {
  DeviceVelocity dv;
  for (size_t i = 0; i < prev.media.size(); ++i) {
    const scene::Medium& m = prev.media[i];
    dv.first.push_back(-1);
    if (!m.velocity || m.procedural) continue;
    const std::string where = fmt::format("media[{}].velocity.grid", i);
    const std::string path = resolve_path(prev, m.file),
                      key = (prev.path.empty() ? "" : prev.path + ": ") + where;
    const std::string source = path + " " + m.velocity->grid;
    // The three components come from one read; each is a grid of its own on the device.
    std::optional<vdb::VelocityGrids> read;
    const char* axis[3] = {"x", "y", "z"};
    for (int c = 0; c < 3; ++c) {
      const uint32_t k =
          grid_index(dv, source + " " + axis[c], fmt::format("{} {}", where, axis[c]), previous, [&] {
            if (!read) read = vdb::load_velocity(path, m.velocity->grid, key);
            return read->c[c];
          });
      if (c == 0) dv.first.back() = int32_t(k);
    }
    if (read && read->nan_voxels > 0)
      dv.notes.push_back(fmt::format("{}: {} NaN/Inf velocity components of {} replaced by 0", where,
                                     read->nan_voxels, m.file));
  }
  return dv;
}

std::vector<glsl::MediumMotion> media_motion(const scene::Scene& s, const scene::Scene& p,
                                             const DeviceMedia& media, const DeviceVelocity& velocity) {
  std::vector<glsl::MediumMotion> moved;
  for (size_t i = 0; i < s.media.size() && i < p.media.size() && i < media.media.size(); ++i) {
    glm::dmat4 now = s.media[i].transform.matrix(), before = p.media[i].transform.matrix();
    const int32_t vel = i < velocity.first.size() ? velocity.first[i] : -1;
    if (now == before && vel < 0) continue;
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
    if (vel >= 0) {
      // The previous frame's contents are where its velocity grids are (a sequence's medium moves inside
      // its files): the box covers them too, within the previous frame's clip box.
      const scene::Medium& pm = p.media[i];
      const scene::Velocity& v = *pm.velocity;
      for (int c = 0; c < 3; ++c) {
        const vdb::DeviceGrid& g = velocity.grids[size_t(vel + c)];
        const glm::dmat4 i2w = before * g.index_to_world;
        glm::dvec3 glo, ghi;
        world_box(g, i2w, glo, ghi);
        lo = glm::min(lo, glm::max(glo, glm::dvec3(pm.bounds_min)));
        hi = glm::max(hi, glm::min(ghi, glm::dvec3(pm.bounds_max)));
        m.prev_world_to_velocity[c] = glm::mat4(glm::inverse(i2w));
      }
      // Grid vectors are in the file's world units (the medium's object space) per second or per frame.
      const double dt = v.unit == "frame" ? 1.0 : 1.0 / double(p.render.fps);
      glm::dmat4 to_world = now;
      to_world[3] = glm::dvec4(0, 0, 0, 1);
      m.velocity_to_world = glm::mat4(to_world * glm::dmat4(glm::dmat3(double(v.scale) * dt)));
      m.velocity = glm::uvec4(uint32_t(vel), uint32_t(vel + 1), uint32_t(vel + 2), 1u);
    }
    m.prev_min = glm::vec4(glm::vec3(lo), 0);
    m.prev_max = glm::vec4(glm::vec3(hi), 0);
    moved.push_back(m);
  }
  return moved;
}

void DeviceGrids::update(gpu::Context& ctx, const GridSet& set, bool wanted) {
  if (!wanted || set.grids.empty()) {
    buffers_.clear();
    sources_.clear();
    table_ = gpu::Buffer();
    return;
  }
  if (!ctx.features().buffer_device_address)
    throw gpu::Error(
        "VDB media need bufferDeviceAddress (the shaders read NanoVDB grids through device addresses), which "
        "this device lacks; pick another device with --device");
  std::vector<gpu::Buffer> buffers;
  std::vector<glm::uvec2> addresses;
  for (size_t i = 0; i < set.grids.size(); ++i) {
    const vdb::DeviceGrid& g = set.grids[i];
    auto same = std::find(sources_.begin(), sources_.end(), set.grid_sources[i]);
    if (same != sources_.end() && buffers_[size_t(same - sources_.begin())].valid()) {
      buffers.push_back(std::move(buffers_[size_t(same - sources_.begin())]));
    } else {
      const std::string name = fmt::format("nanovdb {} '{}'", set.grid_labels[i], g.name);
      try {
        buffers.emplace_back(ctx, name, "scene data", g.nanovdb.size(),
                             fmt::format("NanoVDB float, {} active voxels", g.active_voxels));
      } catch (const gpu::Error& e) {
        throw gpu::Error(
            fmt::format("{}; a grid is one allocation on the device: raise its voxel size or "
                        "split it into several media",
                        e.what()));
      }
      buffers.back().upload(g.nanovdb.data(), g.nanovdb.size());
    }
    const uint64_t a = buffers.back().device_address();
    addresses.emplace_back(uint32_t(a), uint32_t(a >> 32));
  }
  buffers_ = std::move(buffers);
  sources_ = set.grid_sources;
  gpu::keep_uploaded(ctx, table_, true, "nanovdb grid addresses", "scene data", addresses,
                     "u64 device address per grid");
}

void Media::update(const scene::Scene& s) {
  host_ = build_media(s, &host_);
  hetero_ = !s.media.empty();
  haze_ = s.haze.has_value() && s.haze->sigma_t > 0.f;
  haze_params_ = s.haze;
  emission_ = std::any_of(s.media.begin(), s.media.end(),
                          [](const scene::Medium& m) { return m.emission.mode != "none"; });
  // Chromatic only where some medium's multipliers are not all 1; grey scenes keep the grey kernel.
  color_max_ = 1.f;
  chromatic_ = false;
  auto add_color = [&](glm::vec3 c) {
    chromatic_ = chromatic_ || c != glm::vec3(1.f);
    color_max_ = std::max({color_max_, c.x, c.y, c.z});
  };
  if (haze_) add_color(s.haze->sigma_t_color);
  for (const auto& m : s.media) add_color(m.sigma_t_color);
  if (!chromatic_) color_max_ = 1.f;
  // The minorant's control holds in every channel at the grid media's smallest multiplier.
  color_min_ = 1.f;
  for (const auto& m : s.media)
    color_min_ = std::min({color_min_, m.sigma_t_color.x, m.sigma_t_color.y, m.sigma_t_color.z});
  if (!chromatic_) color_min_ = 1.f;
  grids_.update(ctx_, host_, hetero_);
  gpu::keep_uploaded(ctx_, table_, hetero_, "media", "scene data", host_.media, "GpuMedium");
  const auto& maj = host_.majorant;
  // One grid of bounds per scene: volpath (pbrt's plain tracking) reads the majorants alone, the default
  // estimator's trackers the pairs below, whose first holds the same majorants.
  const bool controls_wanted = hetero_ && s.render.estimator != "volpath";
  gpu::keep_uploaded(ctx_, majorant_, hetero_ && !controls_wanted, "majorant grid", "scene data",
                     maj.sigma_max, fmt::format("f32 {}x{}x{}", maj.res.x, maj.res.y, maj.res.z));
  // Two pairs per cell (shaders/volume/medium.glsl): (majorant, minorant) for decomposition tracking, (mean,
  // residual majorant) for residual ratio tracking; each tracker loads one pair per cell.
  std::vector<glm::vec2> controls(2 * maj.sigma_min.size());
  for (size_t i = 0; i < maj.sigma_min.size(); ++i) {
    const float hi = maj.sigma_max[i], lo = maj.sigma_min[i], c = maj.sigma_mean[i];
    controls[2 * i] = {hi, lo};
    // Rounded up: c + r >= hi and c - r <= lo hold in float too (0 stays 0: no lookups where hi = lo).
    const float r = std::max(hi - c, c - lo);
    controls[2 * i + 1] = {c, r > 0 ? std::nextafter(r, std::numeric_limits<float>::infinity()) : 0.f};
  }
  gpu::keep_uploaded(ctx_, minorant_, controls_wanted, "minorant grid", "scene data", controls,
                     fmt::format("f32 pairs (majorant, minorant), (mean, residual) {}x{}x{}", maj.res.x,
                                 maj.res.y, maj.res.z));
}

void Media::update_motion(const scene::Scene& s, const scene::Scene& prev, bool wanted, bool velocity) {
  velocity_ = wanted && velocity ? build_velocity(prev, &velocity_) : DeviceVelocity{};
  velocity_grids_.update(ctx_, velocity_, wanted);
  std::vector<glsl::MediumMotion> moved;
  if (wanted) moved = media_motion(s, prev, host_, velocity_);
  moving_ = uint32_t(moved.size());
  gpu::keep_uploaded(ctx_, motion_, !moved.empty(), "media motion", "scene data", moved, "MediumMotion");
}

std::vector<std::string> Media::notes() const {
  std::vector<std::string> n = host_.notes;
  n.insert(n.end(), velocity_.notes.begin(), velocity_.notes.end());
  return n;
}

void Media::declare(gpu::KernelDecl& k) const {
  if (hetero_) k.define("HAZE_HETERO");
  if (haze_) k.define("HAZE_HAZE");
  if (chromatic_) k.define("HAZE_CHROMATIC");
  if (!hetero_) return;
  if (emission_) k.define("HAZE_EMISSION");
  k.buffer("grids", grids_.table().size(), 8);
  k.buffer("media", table_.size(), sizeof(glsl::GpuMedium));
  if (minorant_.valid()) {
    k.define("HAZE_MINORANT");
    k.buffer("minorant", minorant_.size(), 8);
  } else {
    k.buffer("majorant", majorant_.size(), 4);
  }
}

void Media::declare_default_tracking(gpu::KernelDecl& k) const {
  if (!minorant_.valid()) return;
  // Delta tracking skips the lookup of collisions under the control when a collision needs no more than
  // constants: one grid medium, grey, without emission.
  if (host_.media.size() == 1 && !emission_ && !chromatic_) k.define("HAZE_DECOMPOSITION");
  // The trackers use sigma_t linearly, so one voxel chosen by the trilinear weights serves for the eight,
  // where no value is negative (the shader counts a negative density as 0, which does not commute with the
  // choice). With one grid its accessor is kept over a sample's lookups.
  const auto& v = host_.majorant.value_min;
  if (std::all_of(v.begin(), v.end(), [](float x) { return x >= 0.f; })) {
    k.define("HAZE_STOCHASTIC_LOOKUP");
    if (host_.media.size() == 1) k.define("HAZE_ONE_GRID");
  }
}

void Media::bind(gpu::Bindings& b) const {
  if (!hetero_) return;
  b.set("grids", grids_.table());
  b.set("media", table_);
  if (majorant_.valid()) b.set("majorant", majorant_);
  if (minorant_.valid()) b.set("minorant", minorant_);
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
    g.haze_sigma_t_color = glm::vec4(h.sigma_t_color, 0);
  }
  g.haze_sigma_t_color.w = color_max_;
  g.maj_res = glm::uvec4(glm::max(host_.majorant.res, glm::ivec3(0)), kMaxTrackingSteps);
  g.maj_min = glm::vec4(host_.majorant.world_min, color_min_);
  g.maj_max = glm::vec4(host_.majorant.world_max, 0);
}

}  // namespace haze::volume
