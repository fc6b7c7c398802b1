#include "view/camera.hpp"

#include <algorithm>
#include <cmath>
#include <glm/geometric.hpp>
#include <glm/gtc/constants.hpp>

namespace haze::view {
namespace {

// `v` turned by `angle` radians about the unit axis `k` (Rodrigues).
glm::vec3 rotate(const glm::vec3& v, const glm::vec3& k, float angle) {
  const float c = std::cos(angle), s = std::sin(angle);
  return v * c + glm::cross(k, v) * s + k * glm::dot(k, v) * (1.f - c);
}

// `dir` turned by yaw about `up` and by pitch about the camera's right, keeping it at least 1 degree from
// the up axis either way (past it the view would flip).
glm::vec3 turn(glm::vec3 dir, const glm::vec3& up, float yaw, float pitch) {
  dir = rotate(dir, up, yaw);
  const float limit = glm::radians(1.f);
  const float from_up = std::acos(std::clamp(glm::dot(dir, up), -1.f, 1.f));
  const float next = std::clamp(from_up - pitch, limit, glm::pi<float>() - limit);
  const glm::vec3 right = glm::normalize(glm::cross(dir, up));
  return glm::normalize(rotate(dir, right, from_up - next));
}

}  // namespace

float scene_extent(const glm::vec3& lo, const glm::vec3& hi) {
  if (!(hi.x >= lo.x && hi.y >= lo.y && hi.z >= lo.z)) return 1.f;
  const float d = glm::length(hi - lo);
  return std::isfinite(d) && d > 0.f ? d : 1.f;
}

CameraController::CameraController(const scene::Camera& c, float extent)
    : camera_(c), speed_(0.25f * std::max(extent, 1e-6f)) {}

bool CameraController::update(const CameraInput& in, CameraMode mode) {
  scene::Camera& c = camera_;
  const glm::vec3 up = glm::normalize(c.up);
  glm::vec3 view = c.target - c.position;
  const float dist = glm::length(view);
  glm::vec3 fwd = view / dist;
  bool changed = false;

  const float yaw = -in.look.x * kLookRadiansPerPixel, pitch = -in.look.y * kLookRadiansPerPixel;
  if (in.look != glm::vec2(0)) {
    if (mode == CameraMode::Fly) {
      fwd = turn(fwd, up, yaw, pitch);
      c.target = c.position + fwd * dist;
    } else {
      // The eye moves on the sphere about the target; it keeps looking at it.
      const glm::vec3 back = turn(-fwd, up, -yaw, -pitch);
      c.position = c.target + back * dist;
      fwd = -back;
    }
    changed = true;
  }
  if (mode == CameraMode::Orbit && in.zoom != 0.f) {
    const float d = std::max(dist * std::pow(0.9f, in.zoom), 1e-4f * speed_);
    c.position = c.target - fwd * d;
    changed = true;
  }
  if (in.move != glm::vec3(0) && in.dt > 0) {
    const glm::vec3 right = glm::normalize(glm::cross(fwd, up));
    const float step = speed_ * float(in.dt) * (in.fast ? 4.f : 1.f);
    const glm::vec3 d = (right * in.move.x + up * in.move.y + fwd * in.move.z) * step;
    c.position += d;
    c.target += d;
    changed = true;
  }
  return changed;
}

}  // namespace haze::view
