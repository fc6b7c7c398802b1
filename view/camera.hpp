// The viewer's camera controls: fly (WASD and mouse look) and orbit (about the target). The state is the
// scene's own camera (position, target, up, fov_y), so what the window shows is what "Save scene" writes;
// pure functions of the input, without a window, so that tests can drive them.
#pragma once

#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "scene/scene.hpp"

namespace haze::view {

// One frame's input. Movement keys are -1, 0 or +1 per axis; mouse deltas in pixels.
struct CameraInput {
  glm::vec3 move{0};  // x right (D - A), y up (E - Q), z forward (W - S)
  glm::vec2 look{0};  // mouse delta while looking (fly) or orbiting
  float zoom = 0;     // scroll wheel steps (orbit: towards the target)
  bool fast = false;  // shift: 4x the speed
  double dt = 0;      // seconds since the last frame
};

enum class CameraMode { Fly, Orbit };

class CameraController {
 public:
  // `extent`: the scene's size (the diagonal of its media and surfaces), which sets the speed: a quarter
  // of it per second.
  CameraController(const scene::Camera& c, float extent);

  // Applies one frame's input; true when the camera changed.
  bool update(const CameraInput& in, CameraMode mode);
  const scene::Camera& camera() const { return camera_; }
  void set(const scene::Camera& c) { camera_ = c; }
  float speed() const { return speed_; }  // world units per second

  static constexpr float kLookRadiansPerPixel = 0.004f;

 private:
  scene::Camera camera_;
  float speed_;
};

// The diagonal of the box around the scene's media (their world bounds) and surfaces, 1 if it has neither.
float scene_extent(const glm::vec3& lo, const glm::vec3& hi);

}  // namespace haze::view
