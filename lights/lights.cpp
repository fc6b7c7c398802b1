#include "lights/lights.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace haze::lights {

double Bounds::radius() const {
  if (empty()) return 1;
  const double r = 0.5 * glm::length(glm::dvec3(hi) - glm::dvec3(lo));
  return r > 0 && std::isfinite(r) ? r : 1;
}

std::vector<glsl::GpuLight> light_list(const scene::Lights& s, const std::vector<Emitter>& emitters,
                                       const EnvironmentDistribution* map) {
  std::vector<glsl::GpuLight> out;
  for (const auto& p : s.points) {
    glsl::GpuLight l{};
    l.position = glm::vec4(p.position, float(glsl::LIGHT_POINT));
    l.radiance = glm::vec4(p.color * p.intensity, 0);
    l.direction = glm::vec4(0, -1, 0, 0);
    l.params = glm::vec4(-2.f, -1.5f, 0, 0);  // no falloff anywhere on the sphere
    out.push_back(l);
  }
  for (const auto& sp : s.spots) {
    glsl::GpuLight l{};
    l.position = glm::vec4(sp.position, float(glsl::LIGHT_POINT));
    l.radiance = glm::vec4(sp.color * sp.intensity, 0);
    l.direction = glm::vec4(glm::normalize(sp.direction), 0);
    float cos_outer = std::cos(glm::radians(sp.cone_angle));
    float cos_inner = std::cos(glm::radians(std::max(sp.cone_angle - sp.falloff_angle, 0.f)));
    l.params = glm::vec4(cos_outer, std::max(cos_inner, cos_outer + 1e-6f), 0, 0);
    out.push_back(l);
  }
  for (const auto& e : emitters) {
    glsl::GpuLight l{};
    l.position = glm::vec4(e.v0, float(glsl::LIGHT_TRIANGLE));
    l.radiance = glm::vec4(e.radiance, 0);
    l.direction = glm::vec4(e.v1, 0);
    l.params = glm::vec4(e.v2, 0);
    out.push_back(l);
  }
  if (s.sun) {
    const auto& sun = *s.sun;
    glsl::GpuLight l{};
    l.position = glm::vec4(0, 0, 0, float(glsl::LIGHT_SUN));
    l.radiance = glm::vec4(sun.color * sun.irradiance, 0);
    l.direction = glm::vec4(glm::normalize(sun.direction), 0);
    l.params = glm::vec4(std::cos(glm::radians(sun.angular_diameter * 0.5f)), 0, 0, 0);
    out.push_back(l);
  }
  if (s.environment) {
    const auto& env = *s.environment;
    glsl::GpuLight l{};
    l.position = glm::vec4(0, 0, 0, float(glsl::LIGHT_ENV));
    if (map) {
      // The map's radiance times intensity, turned by rotate about +y.
      const float a = glm::radians(env.rotate);
      l.radiance = glm::vec4(glm::vec3(env.intensity), 0);
      l.direction = glm::vec4(std::cos(a), std::sin(a), 0, 0);
      l.params = glm::vec4(float(map->width), float(map->height), 0, 0);
    } else {
      l.radiance = glm::vec4(env.color * env.intensity, 0);
    }
    out.push_back(l);
  }
  return out;
}

std::vector<double> light_powers(const std::vector<glsl::GpuLight>& list, double env_integral,
                                 double radius) {
  const double disc = M_PI * radius * radius;
  std::vector<double> out;
  for (const glsl::GpuLight& l : list) {
    const double Y = glsl::luminance(glm::vec3(l.radiance));
    double power = 0;
    switch (uint32_t(l.position.w)) {
      case glsl::LIGHT_POINT: {
        // Solid angle of the smoothstep falloff from cos_outer to cos_inner: full inside, half over the ramp.
        // A spot's cone is at most 90 degrees (cos_outer >= 0); a point's ramp lies below -1 (whole sphere).
        const double co = l.params.x, ci = l.params.y;
        const double solid = ci <= -1 ? 4 * M_PI : 2 * M_PI * ((1 - ci) + 0.5 * (ci - co));
        power = Y * solid;
        break;
      }
      case glsl::LIGHT_TRIANGLE: {
        const glm::dvec3 v0(l.position), v1(l.direction), v2(l.params);
        power = 2 * M_PI * Y * 0.5 * glm::length(glm::cross(v1 - v0, v2 - v0));
        break;
      }
      case glsl::LIGHT_SUN:
        power = Y * disc;
        break;
      case glsl::LIGHT_ENV:
        power = Y * env_integral * disc;
        break;
    }
    out.push_back(std::isfinite(power) ? std::max(power, 0.0) : 0.0);
  }
  return out;
}

AliasTable alias_table(const std::vector<double>& weights) {
  const size_t n = weights.size();
  AliasTable t;
  t.threshold.assign(n, uint32_t(kRandomOne));
  t.alias.resize(n);
  t.pmf.assign(n, 0.0);
  for (size_t i = 0; i < n; ++i) t.alias[i] = uint32_t(i);
  if (n == 0) return t;
  if (n > kRandomOne) throw Error(fmt::format("{} lights: at most 2^24 can be chosen from", n));
  double total = 0;
  for (double w : weights) total += w;
  if (total > 0 && std::isfinite(total)) {
    // Vose: slots under 1 are kept with their scaled weight and topped up by one over 1.
    std::vector<double> q(n);
    std::vector<size_t> small, large;
    for (size_t i = 0; i < n; ++i) {
      q[i] = weights[i] * double(n) / total;
      (q[i] < 1 ? small : large).push_back(i);
    }
    std::vector<double> keep(n, 1.0);
    while (!small.empty() && !large.empty()) {
      const size_t s = small.back(), l = large.back();
      small.pop_back();
      large.pop_back();
      keep[s] = q[s];
      t.alias[s] = uint32_t(l);
      q[l] = (q[l] + q[s]) - 1;
      (q[l] < 1 ? small : large).push_back(l);
    }
    // What remains is 1 up to rounding: kept whole.
    for (size_t i = 0; i < n; ++i) {
      uint64_t T = uint64_t(std::llround(keep[i] * double(kRandomOne)));
      // A slot's remainders are r0 + k n with r0 < n: a threshold of n keeps at least one of them, so no
      // light of positive weight is out of reach (its probability is what the count below says).
      if (weights[i] > 0) T = std::max<uint64_t>(T, n);
      t.threshold[i] = uint32_t(std::min(T, kRandomOne));
      if (t.threshold[i] == kRandomOne) t.alias[i] = uint32_t(i);
    }
  }
  // The exact probabilities of the shader's rule: slot s holds U in [ceil(s 2^24 / n), ceil((s+1) 2^24 / n)),
  // whose remainders U n - s 2^24 step by n from r0.
  for (size_t s = 0; s < n; ++s) {
    const uint64_t u0 = (s * kRandomOne + n - 1) / n, u1 = ((s + 1) * kRandomOne + n - 1) / n;
    const uint64_t m = u1 - u0, r0 = u0 * n - s * kRandomOne, T = t.threshold[s];
    const uint64_t kept = T > r0 ? std::min<uint64_t>(m, (T - r0 + n - 1) / n) : 0;
    t.pmf[s] += double(kept) / double(kRandomOne);
    t.pmf[t.alias[s]] += double(m - kept) / double(kRandomOne);
  }
  return t;
}

void apply_choice(std::vector<glsl::GpuLight>& list, const AliasTable& t) {
  for (size_t i = 0; i < list.size(); ++i) {
    list[i].radiance.w = float(t.pmf[i]);
    list[i].direction.w = float(t.threshold[i]);  // integers below 2^24 + 1 are exact in float
    list[i].params.w = float(t.alias[i]);
  }
}

void Lights::keep_map(const std::string& path) {
  std::error_code ec;
  const uintmax_t bytes = std::filesystem::file_size(path, ec);
  const int64_t mtime = int64_t(std::filesystem::last_write_time(path, ec).time_since_epoch().count());
  if (map_ && map_->path == path && map_->bytes == bytes && map_->mtime == mtime) return;
  const std::string key = "lights.environment.file";
  EnvironmentMap m = read_environment_map(path, key);
  ++map_reads_;
  const uint64_t texel_bytes = uint64_t(m.texels.size()) * sizeof(glm::vec3);
  const uint64_t range = ctx_.limits().maxStorageBufferRange;
  if (texel_bytes > range)
    throw Error(
        fmt::format("{} {}: {}x{} texels need {:.0f} MiB, over this device's storage buffer range of {:.0f} "
                    "MiB; scale the map down",
                    key, path, m.width, m.height, texel_bytes / 1048576.0, range / 1048576.0));
  Map next;
  next.path = path;
  next.bytes = bytes;
  next.mtime = mtime;
  next.distribution = build_distribution(m);
  if (m.replaced() > 0)
    next.note = fmt::format("{} {}: {} texel channels replaced by 0 ({} NaN, {} infinite, {} negative)", key,
                            path, m.replaced(), m.nan, m.inf, m.negative);
  const auto& d = next.distribution;
  const std::string size = fmt::format("{}x{}", m.width, m.height);
  next.texels = gpu::Buffer(ctx_, "environment map " + size, "scene data", texel_bytes, "RGB32F");
  next.texels.upload(m.texels);
  next.conditional = gpu::Buffer(ctx_, "environment conditional CDF " + size, "scene data",
                                 d.conditional.size() * sizeof(float), "f32");
  next.conditional.upload(d.conditional);
  next.marginal = gpu::Buffer(ctx_, "environment marginal CDF " + size, "scene data",
                              d.marginal.size() * sizeof(float), "f32");
  next.marginal.upload(d.marginal);
  map_ = std::move(next);
}

void Lights::update(const scene::Lights& l, const std::vector<Emitter>& emitters, const Bounds& bounds) {
  const bool map = l.environment && !l.environment->file.empty();
  if (map)
    keep_map(l.environment->file);
  else
    map_.reset();
  scene_ = l;
  list_ = light_list(l, emitters, map_ ? &map_->distribution : nullptr);
  local_ = l.points.size() + l.spots.size();
  area_ = !emitters.empty();

  Bounds b = bounds;
  for (const auto& p : l.points) b.add(p.position);
  for (const auto& s : l.spots) b.add(s.position);
  for (const auto& e : emitters) {
    b.add(e.v0);
    b.add(e.v1);
    b.add(e.v2);
  }
  double env_integral = 0;
  if (l.environment) env_integral = map_ ? map_->distribution.luminance_integral : 4 * M_PI;
  powers_ = light_powers(list_, env_integral, b.radius());
  choice_ = alias_table(l.choice == "uniform" ? std::vector<double>(list_.size(), 1.0) : powers_);
  apply_choice(list_, choice_);
  gpu::keep_uploaded(ctx_, buffer_, !list_.empty(), "lights", "scene data", list_, "GpuLight");
}

std::vector<std::string> Lights::notes() const {
  if (map_ && !map_->note.empty()) return {map_->note};
  return {};
}

void Lights::declare(gpu::KernelDecl& k) const {
  if (scene_.sun) k.define("HAZE_SUN");
  if (scene_.environment) k.define("HAZE_ENV");
  if (local_ > 0) k.define("HAZE_LOCAL");
  if (area_) k.define("HAZE_AREA");
  if (any()) k.buffer("lights", list_.size() * sizeof(glsl::GpuLight), sizeof(glsl::GpuLight));
  if (map_) {
    k.define("HAZE_ENV_MAP");
    k.buffer("env_texels", map_->texels.size(), 12)
        .buffer("env_conditional", map_->conditional.size(), 4)
        .buffer("env_marginal", map_->marginal.size(), 4);
  }
}

void Lights::bind(gpu::Bindings& b) const {
  if (any()) b.set("lights", buffer_);
  if (map_)
    b.set("env_texels", map_->texels)
        .set("env_conditional", map_->conditional)
        .set("env_marginal", map_->marginal);
}

void Lights::fill(glsl::GpuScene& g) const {
  g.counts.y = uint32_t(list_.size());
  g.counts.z = uint32_t(local_);
  // A map's radiance reaches background() through its own buffers.
  if (scene_.environment && !map_)
    g.env = glm::vec4(scene_.environment->color * scene_.environment->intensity, 0);
  // The direction for any sun (the walk's sun lobe reads it); cos 1: no visible disk.
  g.sun_direction = glm::vec4(0, 1, 0, 1);
  if (!scene_.sun) return;
  const auto& sun = *scene_.sun;
  g.sun_direction = glm::vec4(glm::normalize(sun.direction), 1);
  if (sun.angular_diameter > 0.f) {
    float cos_max = std::cos(glm::radians(sun.angular_diameter * 0.5f));
    float omega = 2.f * glsl::PI * (1.f - cos_max);
    g.sun_direction.w = cos_max;
    g.sun_radiance = glm::vec4(sun.color * sun.irradiance / std::max(omega, 1e-30f), 0);
  }
}

}  // namespace haze::lights
