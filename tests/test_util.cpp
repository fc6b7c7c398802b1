#include "test_util.hpp"

#include <cmath>

namespace haze::test {

gpu::Context& context() {
  static gpu::Context ctx{gpu::ContextOptions{}};
  return ctx;
}

scene::Scene make_scene(const nlohmann::json& j) {
  return scene::from_json(j, "test scene", "");
}

Estimate estimate(const render::Renderer& r, uint32_t sum, uint32_t sq) {
  std::vector<float> acc = r.accum();
  size_t pixels = acc.size() / glsl::ACC_STRIDE;
  double n = r.samples();
  Estimate e;
  for (size_t p = 0; p < pixels; ++p) {
    double s = acc[p * glsl::ACC_STRIDE + sum], s2 = acc[p * glsl::ACC_STRIDE + sq];
    double m = s / n;
    double var = std::max(0.0, (s2 / n - m * m) * n / (n - 1));
    e.mean.push_back(m);
    e.var_of_mean.push_back(var / n);
  }
  return e;
}

std::vector<glm::dvec3> camera_directions(const scene::Scene& s) {
  const auto& c = s.camera;
  glm::dvec3 fwd = glm::normalize(glm::dvec3(c.target - c.position));
  glm::dvec3 right = glm::normalize(glm::cross(fwd, glm::dvec3(c.up)));
  glm::dvec3 up = glm::cross(right, fwd);
  double th = std::tan(glm::radians(double(c.fov_y)) * 0.5);
  double aspect = double(s.render.width) / s.render.height;
  std::vector<glm::dvec3> dirs;
  for (int y = 0; y < s.render.height; ++y)
    for (int x = 0; x < s.render.width; ++x) {
      double nx = (x + 0.5) / s.render.width * 2 - 1, ny = (y + 0.5) / s.render.height * 2 - 1;
      dirs.push_back(glm::normalize(fwd + nx * th * aspect * right - ny * th * up));
    }
  return dirs;
}

double z_score(const Estimate& e, const std::vector<double>& ref) {
  double diff = 0, var = 0;
  for (size_t p = 0; p < ref.size(); ++p) {
    if (std::isnan(ref[p])) continue;
    diff += e.mean[p] - ref[p];
    var += e.var_of_mean[p];
  }
  return var > 0 ? diff / std::sqrt(var) : (diff == 0 ? 0 : 1e9);
}

double integrate(const std::function<double(double)>& f, double a, double b, int n) {
  if (n % 2) ++n;
  double h = (b - a) / n, s = f(a) + f(b);
  for (int i = 1; i < n; ++i) s += f(a + i * h) * (i % 2 ? 4 : 2);
  return s * h / 3;
}

}  // namespace haze::test
