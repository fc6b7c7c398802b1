// Surfaces in the renderer: an emitting enclosure (closed form), motion vectors against independent CPU
// geometry, and depth gradients against finite differences. Same significance rule as estimator_test:
// alpha = 1e-4 two-sided, |z| < 3.89, fixed seeds.
#include <gtest/gtest.h>

#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <iostream>

#include "test_util.hpp"
#include "volume/device_scene.hpp"
#include "volume/glsl.hpp"

namespace haze::test {
namespace {

constexpr double kZ = 3.89;
using nlohmann::json;

// Inside a closed box whose walls all emit Le and reflect with albedo a, the radiance is Le / (1 - a)
// everywhere, also through a non-absorbing haze filling it (a furnace with surfaces).
TEST(SurfaceRender, EmittingEnclosureIsAFurnace) {
  const double Le = 0.5, a = 0.6;
  json j = {{"camera", {{"position", {0.3, 0.2, 0.5}}, {"target", {-0.2, 0, -1}}, {"fov_y", 70}}},
            {"surfaces",
             {{{"mesh", {{"kind", "box"}, {"size", {4, 3, 5}}}},
               {"albedo", {a, a, a}},
               {"emission", {Le, Le, Le}}}}},
            {"haze",
             {{"sigma_t", 0.4},
              {"albedo", {1, 1, 1}},
              {"g", 0.3},
              {"bounded", true},
              {"bounds_min", {-2, -1.5, -2.5}},
              {"bounds_max", {2, 1.5, 2.5}}}},
            {"render", {{"width", 8}, {"height", 8}, {"max_depth", 256}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  EXPECT_TRUE(r.features().surfaces);
  EXPECT_TRUE(r.features().area);
  r.add_samples(512);
  Estimate e = estimate(r, glsl::ACC_L, glsl::ACC_L2);
  double z = z_score(e, std::vector<double>(e.mean.size(), Le / (1 - a)));
  double avg = 0, sd = 0;
  for (size_t p = 0; p < e.mean.size(); ++p) avg += e.mean[p] / e.mean.size(), sd += e.var_of_mean[p];
  std::cout << "z = " << z << ", mean " << avg << ", sd of the mean " << std::sqrt(sd) / e.mean.size()
            << "\n";
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  EXPECT_EQ(context().validation_messages(), 0u);
}

// A plane (a wall at z = 0 facing the camera) moves while the camera moves; the G-buffer's motion of each
// pixel must lead to the previous frame's pixel whose ray hits the plane at the same object-space point.
TEST(SurfaceRender, MotionVectorsReprojectToTheSamePointOnMovingGeometry) {
  auto make = [](glm::vec3 cam, glm::vec3 target, glm::vec3 plane_pos, float plane_rot) {
    return json{
        {"camera",
         {{"position", {cam.x, cam.y, cam.z}}, {"target", {target.x, target.y, target.z}}, {"fov_y", 50}}},
        {"surfaces",
         {{{"mesh", {{"kind", "plane"}, {"size", {40, 40}}}},
           {"transform",
            {{"translate", {plane_pos.x, plane_pos.y, plane_pos.z}}, {"rotate", {0, plane_rot, 0}}}}}}},
        {"render", {{"width", 24}, {"height", 16}, {"pixel_jitter", false}}}};
  };
  scene::Scene prev = make_scene(make({0, 0, 5}, {0, 0, 0}, {0, 0, 0}, 0));
  scene::Scene cur = make_scene(make({0.4, 0.2, 4.6}, {0.1, 0, 0}, {0.3, -0.1, -0.2}, 8));
  render::Renderer r(context(), cur, 0, &prev);
  r.add_samples(1);
  render::Image img = r.resolve();

  glm::dmat4 o2w_prev = glm::dmat4(prev.surfaces[0].transform.matrix());
  glm::dmat4 o2w_cur = glm::dmat4(cur.surfaces[0].transform.matrix());
  auto dirs = camera_directions(cur);
  auto pb = volume::camera_basis(prev.camera, prev.render);
  glm::dvec2 size(cur.render.width, cur.render.height);
  double worst = 0;
  int checked = 0;
  for (int y = 0; y < cur.render.height; ++y)
    for (int x = 0; x < cur.render.width; ++x) {
      double depth = img.g(x, y, glsl::G_DEPTH);
      ASSERT_GT(depth, 0) << "every pixel sees the plane";
      glm::dvec3 X = glm::dvec3(cur.camera.position) + depth * dirs[size_t(y) * cur.render.width + x];
      glm::dvec3 obj = glm::dvec3(glm::inverse(o2w_cur) * glm::dvec4(X, 1));
      // The previous frame's ray through the reprojected position, intersected with the plane's old pose.
      glm::dvec2 q = glm::dvec2(x + 0.5, y + 0.5) +
                     glm::dvec2(img.g(x, y, glsl::G_MOTION), img.g(x, y, glsl::G_MOTION + 1));
      glm::dvec3 o(prev.camera.position);
      glm::dvec2 ndc = q / size * 2.0 - 1.0;
      glm::dvec3 d =
          glm::normalize(glm::dvec3(pb.forward) + ndc.x * glm::dvec3(pb.right) - ndc.y * glm::dvec3(pb.up));
      glm::dmat4 w2o = glm::inverse(o2w_prev);
      glm::dvec3 lo = glm::dvec3(w2o * glm::dvec4(o, 1)), ld = glm::dvec3(w2o * glm::dvec4(d, 0));
      double t = -lo.z / ld.z;  // the plane is z = 0 in object space
      glm::dvec3 obj_prev = lo + t * ld;
      // Compare in units of the pixel footprint at that depth.
      double footprint = 2 * std::tan(glm::radians(25.0)) * depth / cur.render.height;
      worst = std::max(worst, glm::length(obj_prev - obj) / footprint);
      ++checked;
    }
  EXPECT_EQ(checked, cur.render.width * cur.render.height);
  EXPECT_LT(worst, 0.01) << "worst reprojection error, in pixels";
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The depth gradient is the depth of the +x/+y neighbours' rays on the hit plane minus the centre's: on a
// plane it equals the finite difference of the depth image.
TEST(SurfaceRender, DepthGradientMatchesFiniteDifferences) {
  json j = {
      {"camera", {{"position", {0.5, 1.0, 4}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
      {"surfaces",
       {{{"mesh", {{"kind", "plane"}, {"size", {30, 30}}}}, {"transform", {{"rotate", {-70, 20, 0}}}}}}},
      {"render", {{"width", 20}, {"height", 14}, {"pixel_jitter", false}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(1);
  render::Image img = r.resolve();
  int checked = 0;
  for (int y = 0; y + 1 < s.render.height; ++y)
    for (int x = 0; x + 1 < s.render.width; ++x) {
      double z = img.g(x, y, glsl::G_DEPTH), zx = img.g(x + 1, y, glsl::G_DEPTH),
             zy = img.g(x, y + 1, glsl::G_DEPTH);
      if (z <= 0 || zx <= 0 || zy <= 0) continue;
      EXPECT_NEAR(img.g(x, y, glsl::G_DDEPTH), zx - z, 1e-4 * z) << x << "," << y;
      EXPECT_NEAR(img.g(x, y, glsl::G_DDEPTH + 1), zy - z, 1e-4 * z) << x << "," << y;
      ++checked;
    }
  EXPECT_GT(checked, 100);
  // The encoded normal decodes to the plane's normal, facing the camera.
  glm::vec3 n = glsl::oct_decode(glm::vec2(img.g(5, 5, glsl::G_NORMAL), img.g(5, 5, glsl::G_NORMAL + 1)));
  glm::vec3 expected = glm::normalize(glm::vec3(s.surfaces[0].transform.matrix() * glm::vec4(0, 0, 1, 0)));
  EXPECT_NEAR(std::abs(glm::dot(n, expected)), 1.0f, 1e-4f);
  EXPECT_EQ(context().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze::test
