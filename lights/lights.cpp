#include "lights/lights.hpp"

#include <algorithm>
#include <cmath>

namespace haze::lights {

std::vector<glsl::GpuLight> light_list(const scene::Lights& s, const std::vector<Emitter>& emitters) {
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
    glsl::GpuLight l{};
    l.position = glm::vec4(0, 0, 0, float(glsl::LIGHT_ENV));
    l.radiance = glm::vec4(s.environment->color * s.environment->intensity, 0);
    out.push_back(l);
  }
  return out;
}

void Lights::update(const scene::Lights& l, const std::vector<Emitter>& emitters) {
  scene_ = l;
  list_ = light_list(l, emitters);
  local_ = l.points.size() + l.spots.size();
  area_ = !emitters.empty();
  gpu::keep_uploaded(ctx_, buffer_, !list_.empty(), "lights", "scene data", list_, "GpuLight");
}

void Lights::declare(gpu::KernelDecl& k) const {
  if (scene_.sun) k.define("HAZE_SUN");
  if (scene_.environment) k.define("HAZE_ENV");
  if (local_ > 0) k.define("HAZE_LOCAL");
  if (area_) k.define("HAZE_AREA");
  if (any()) k.buffer("lights", list_.size() * sizeof(glsl::GpuLight), sizeof(glsl::GpuLight));
}

void Lights::bind(gpu::Bindings& b) const {
  if (any()) b.set("lights", buffer_);
}

void Lights::fill(glsl::GpuScene& g) const {
  g.counts.y = uint32_t(list_.size());
  g.counts.z = uint32_t(local_);
  if (scene_.environment) g.env = glm::vec4(scene_.environment->color * scene_.environment->intensity, 0);
  g.sun_direction = glm::vec4(0, 1, 0, 1);  // cos 1: no visible disk
  if (scene_.sun && scene_.sun->angular_diameter > 0.f) {
    const auto& sun = *scene_.sun;
    float cos_max = std::cos(glm::radians(sun.angular_diameter * 0.5f));
    float omega = 2.f * glsl::PI * (1.f - cos_max);
    g.sun_direction = glm::vec4(glm::normalize(sun.direction), cos_max);
    g.sun_radiance = glm::vec4(sun.color * sun.irradiance / std::max(omega, 1e-30f), 0);
  }
}

}  // namespace haze::lights
