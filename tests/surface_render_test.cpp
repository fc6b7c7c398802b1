// Surfaces in the renderer: an emitting enclosure (closed form), motion vectors against independent CPU
// geometry, and depth gradients against finite differences. Same significance rule as estimator_test:
// alpha = 1e-4 two-sided, |z| < 3.89, fixed seeds.
#include <gtest/gtest.h>
#include <stb/stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <iostream>

#include "render/output.hpp"
#include "shaders/glsl.hpp"
#include "surfaces/texture.hpp"
#include "temp_dir.hpp"
#include "test_util.hpp"

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
  EXPECT_TRUE(r.has_feature("SURFACES"));
  EXPECT_TRUE(r.has_feature("AREA"));
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
  auto pb = render::camera_basis(prev.camera, prev.render);
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

// Bilinear filtering with wrap-around, written apart from the shader's: v = 0 is the image's bottom row,
// texel centres at half-integers.
glm::dvec3 bilinear_reference(const surfaces::Texture& t, double u, double v) {
  const int W = int(t.width), H = int(t.height);
  double px = (u - std::floor(u)) * W - 0.5, py = (1 - (v - std::floor(v))) * H - 0.5;
  int x0 = int(std::floor(px)), y0 = int(std::floor(py));
  double fx = px - x0, fy = py - y0;
  auto at = [&](int x, int y) {
    return glm::dvec3(t.at(uint32_t((x % W + W) % W), uint32_t((y % H + H) % H)));
  };
  return (1 - fy) * ((1 - fx) * at(x0, y0) + fx * at(x0 + 1, y0)) +
         fy * ((1 - fx) * at(x0, y0 + 1) + fx * at(x0 + 1, y0 + 1));
}

// Two planes share one 8-bit sRGB texture with different tints; the right one is mirrored (scale x = -1),
// which reverses its triangles' winding. The G-buffer albedo must be tint * texture at the uv of the hit.
TEST(SurfaceRender, AlbedoTextureIsFilteredAtTheHitUv) {
  TempDir dir("haze_texture");
  const int W = 5, H = 4;
  unsigned char px[W * H * 3];
  for (int i = 0; i < W * H * 3; ++i) px[i] = (unsigned char)((i * 97 + 31) % 256);
  const std::string png = (dir.path() / "albedo.png").string();
  ASSERT_TRUE(stbi_write_png(png.c_str(), W, H, 3, px, W * 3));
  const glm::dvec3 tint[2] = {{1, 0.5, 0.8}, {0.9, 1, 0.7}};
  json j = {{"camera", {{"position", {0, 0, 3.5}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"surfaces",
             {{{"mesh", {{"kind", "plane"}, {"size", {1.8, 1.8}}}},
               {"albedo", {tint[0].x, tint[0].y, tint[0].z}},
               {"albedo_texture", png},
               {"transform", {{"translate", {-1, 0, 0}}}}},
              {{"mesh", {{"kind", "plane"}, {"size", {1.8, 1.8}}}},
               {"albedo", {tint[1].x, tint[1].y, tint[1].z}},
               {"albedo_texture", png},
               {"transform", {{"translate", {1, 0, 0}}, {"scale", {-1, 1, 1}}}}}}},
            {"render", {{"width", 48}, {"height", 24}, {"pixel_jitter", false}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  EXPECT_TRUE(r.has_feature("TEXTURE"));
  r.add_samples(1);
  render::Image img = r.resolve();
  surfaces::Texture tex = surfaces::load_texture(png);
  auto dirs = camera_directions(s);
  int seen[2] = {0, 0};
  double worst = 0;
  for (int y = 0; y < s.render.height; ++y)
    for (int x = 0; x < s.render.width; ++x) {
      double depth = img.g(x, y, glsl::G_DEPTH);
      if (depth <= 0) continue;
      uint32_t inst = glm::floatBitsToUint(float(img.g(x, y, glsl::G_INSTANCE)));
      ASSERT_LT(inst, 2u);
      glm::dvec3 X = glm::dvec3(s.camera.position) + depth * dirs[size_t(y) * s.render.width + x];
      // Object space x (the plane's u axis), undoing each placement; v follows y on both.
      double ox = inst == 0 ? X.x + 1 : 1 - X.x;
      glm::dvec3 expected = tint[inst] * bilinear_reference(tex, ox / 1.8 + 0.5, X.y / 1.8 + 0.5);
      for (int c = 0; c < 3; ++c)
        worst = std::max(worst, std::abs(img.g(x, y, glsl::G_ALBEDO + c) - expected[c]));
      ++seen[inst];
    }
  EXPECT_GT(seen[0], 200);
  EXPECT_GT(seen[1], 200);
  EXPECT_LT(worst, 2e-3) << "largest albedo error";
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The enclosure furnace with the albedo in a texture (tint 1): a path that used the tint instead of the
// texture at any bounce would not converge to Le / (1 - a).
TEST(SurfaceRender, TexturedEnclosureIsAFurnace) {
  TempDir dir("haze_texture");
  const double Le = 0.5, a = 0.6;  // 0.6 * 65535 is an integer: exact in the shaders' 16-bit texels
  const float texels[2 * 2 * 3] = {0.6f, 0.6f, 0.6f, 0.6f, 0.6f, 0.6f, 0.6f, 0.6f, 0.6f, 0.6f, 0.6f, 0.6f};
  const std::string hdr = (dir.path() / "grey.hdr").string();
  ASSERT_TRUE(stbi_write_hdr(hdr.c_str(), 2, 2, 3, texels));
  const float stored = surfaces::load_texture(hdr).at(0, 0).r;  // RGBE rounds 0.6
  json j = {{"camera", {{"position", {0.3, 0.2, 0.5}}, {"target", {-0.2, 0, -1}}, {"fov_y", 70}}},
            {"surfaces",
             {{{"mesh", {{"kind", "box"}, {"size", {4, 3, 5}}}},
               {"albedo", {1, 1, 1}},
               {"albedo_texture", hdr},
               {"emission", {Le, Le, Le}}}}},
            {"render", {{"width", 8}, {"height", 8}, {"max_depth", 256}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  Estimate e = estimate(r, glsl::ACC_L, glsl::ACC_L2);
  double albedo = std::round(double(stored) * 65535) / 65535;
  double z = z_score(e, std::vector<double>(e.mean.size(), Le / (1 - albedo)));
  std::cout << "z = " << z << " (texture albedo " << albedo << ", nominal " << a << ")\n";
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Sunlit haze under a horizontal window of open slats, vertical sun (a delta direction): the slats cast
// sharp strips of shadow. Along each camera ray the lit intervals are exact, and on each the single-
// scattering integral sigma_s p E exp(-sigma (t + 1 - y(t))) has a closed form.
TEST(SurfaceRender, HazeUnderSlatsMatchesTheClosedFormSlab) {
  const double sigma = 0.5, albedo = 0.8, g = 0.3, E = 2.0;
  const double slat_half = 0.05;  // half the slat thickness; the chord (spacing) is 0.5
  json j = {{"camera", {{"position", {0, 0, -2.9}}, {"target", {0.2, 0.1, 3}}, {"fov_y", 50}}},
            {"surfaces",
             {{{"mesh",
                {{"kind", "window"},
                 {"width", 4},
                 {"height", 4},
                 {"frame", 0},
                 {"slats", 8},
                 {"slat_thickness", 2 * slat_half},
                 {"slat_angle", 0}}},
               {"albedo", {0, 0, 0}},
               {"transform", {{"translate", {0, 2, 0}}, {"rotate", {-90, 0, 0}}}}}}},
            {"haze",
             {{"sigma_t", sigma},
              {"albedo", {albedo, albedo, albedo}},
              {"g", g},
              {"bounded", true},
              {"bounds_min", {-3, -1, -3}},
              {"bounds_max", {3, 1, 3}}}},
            {"lights", {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", E}, {"angular_diameter", 0}}}}},
            {"render", {{"width", 16}, {"height", 12}, {"pixel_jitter", false}, {"max_depth", 1}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  const glm::dvec3 o(s.camera.position);
  // Shadow strips: slat k covers world z in c_k +- slat_half for |x| < 2 (the window rotated to face up).
  std::vector<double> strips;
  for (int k = 0; k < 8; ++k) strips.push_back(-1.75 + 0.5 * k);
  auto shadowed = [&](glm::dvec3 p) {
    if (std::abs(p.x) >= 2) return false;
    for (double c : strips)
      if (std::abs(p.z - c) < slat_half) return true;
    return false;
  };
  std::vector<double> ref;
  double lit_fraction = 0, length = 0;
  for (glm::dvec3 d : camera_directions(s)) {
    // Exit of the haze box (the camera is inside it).
    double t_exit = 1e30;
    const glm::dvec3 lo(-3, -1, -3), hi(3, 1, 3);
    for (int a = 0; a < 3; ++a)
      if (d[a] != 0) t_exit = std::min(t_exit, ((d[a] > 0 ? hi[a] : lo[a]) - o[a]) / d[a]);
    // Breakpoints where the ray crosses a strip edge or the window's x edges.
    std::vector<double> ts = {0, t_exit};
    auto cross = [&](int axis, double value) {
      double t = (value - o[axis]) / d[axis];
      if (d[axis] != 0 && t > 0 && t < t_exit) ts.push_back(t);
    };
    cross(0, -2), cross(0, 2);
    for (double c : strips) cross(2, c - slat_half), cross(2, c + slat_half);
    std::sort(ts.begin(), ts.end());
    const double k = sigma * (1 - d.y);  // exp(-sigma t) exp(-sigma (1 - y(t))), y(t) = o.y + t d.y
    const double p = glsl::hg_phase(float(d.y), float(g));
    double L = 0;
    for (size_t i = 0; i + 1 < ts.size(); ++i) {
      double t0 = ts[i], t1 = ts[i + 1];
      length += t1 - t0;
      if (shadowed(o + 0.5 * (t0 + t1) * d)) continue;
      lit_fraction += t1 - t0;
      L += std::exp(-sigma * (1 - o.y)) * (std::exp(-k * t0) - std::exp(-k * t1)) / k;
    }
    ref.push_back(sigma * albedo * p * E * L);
  }
  Estimate e = estimate(r, glsl::ACC_L, glsl::ACC_L2);
  double z = z_score(e, ref);
  std::cout << "z = " << z << ", lit fraction of the rays " << lit_fraction / length << "\n";
  EXPECT_LT(lit_fraction / length, 0.9);  // the slats really shade a good part of the rays
  EXPECT_LT(std::abs(z), kZ) << "z = " << z << " mean[0] " << e.mean[0] << " ref[0] " << ref[0];
  EXPECT_EQ(context().validation_messages(), 0u);
}

// A dark emitter (albedo 2e-4, below DEMOD_MIN_ALBEDO) in front of a sunlit grey wall: its emission stays
// out of the demodulated signal and comes back after remodulation, so the denoised radiance on it is the
// noisy mean, not emission / 1e-3 cut down by the firefly clamp and the filter.
TEST(SurfaceRender, DarkEmitterKeepsItsRadianceThroughTheDenoiser) {
  const json j = {
      {"camera", {{"position", {0, 0, 3}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
      {"surfaces",
       {{{"mesh", {{"kind", "plane"}, {"size", {10, 10}}}},
         {"albedo", {0.5, 0.5, 0.5}},
         {"transform", {{"translate", {0, 0, -1}}}}},
        {{"mesh", {{"kind", "box"}, {"size", {0.8, 0.8, 0.8}}}},
         {"albedo", {2e-4, 2e-4, 2e-4}},
         {"emission", {2, 1.5, 1}}}}},
      {"lights", {{"sun", {{"direction", {0.3, 0.5, 1}}, {"irradiance", 3}, {"angular_diameter", 0}}}}},
      {"render", {{"width", 32}, {"height", 32}, {"max_depth", 2}, {"pixel_jitter", false}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render::Image img;
  for (uint32_t f = 0; f < 4; ++f) {
    if (f > 0) r.set_scene(s, f, &s);
    r.add_samples(4);
    img = r.resolve();
  }
  ASSERT_TRUE(img.surface_denoised.has_value());
  // The emitter's pixels whose 3x3 neighbourhood is all emitter (the box is instance 1).
  auto box = [&](int x, int y) {
    return glm::floatBitsToUint(img.g(x, y, glsl::G_INSTANCE)) == 1u && img.g(x, y, glsl::G_DEPTH) > 0;
  };
  glm::dvec3 noisy(0), denoised(0);
  int n = 0;
  for (int y = 1; y + 1 < img.height; ++y)
    for (int x = 1; x + 1 < img.width; ++x) {
      bool inner = true;
      for (int d = 0; d < 9; ++d) inner = inner && box(x + d % 3 - 1, y + d / 3 - 1);
      if (!inner) continue;
      ++n;
      for (int c = 0; c < 3; ++c) noisy[c] += img.at(x, y, glsl::OUT_SURF + c);
      denoised += glm::dvec3(img.surface_denoised->colour[size_t(y) * img.width + x]);
    }
  ASSERT_GT(n, 20);
  for (int c = 0; c < 3; ++c) {
    const double rel = denoised[c] / noisy[c] - 1;
    std::cout << "channel " << c << ": noisy " << noisy[c] / n << ", denoised " << denoised[c] / n
              << ", relative difference " << rel << "\n";
    EXPECT_LT(std::abs(rel), 4e-4) << c;  // measured 1.5e-4 (the noisy mean carries reflected sunlight)
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The camera hits' emission is a layer (acc_emit, out_emit), a trace and resolve code path and a TAA
// permutation only in scenes with emissive surfaces: without one there is no such buffer in the ledger, no
// such binding in the kernels, no surface_emission EXR layer; adding an emitter to the same renderer brings
// them. Catches: the layers allocated for every scene (as before this test).
TEST(SurfaceRender, EmissionLayerOnlyInScenesWithEmitters) {
  json j = {{"camera", {{"position", {0, 0, 3}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"surfaces", {{{"mesh", {{"kind", "plane"}, {"size", {10, 10}}}}, {"albedo", {0.5, 0.5, 0.5}}}}},
            {"lights", {{"sun", {{"direction", {0.3, 0.5, 1}}, {"irradiance", 3}}}}},
            {"render", {{"width", 16}, {"height", 16}}}};
  auto traces_emission = [&](const render::Renderer& r) {
    for (const auto& b : r.trace_decl().bindings())
      if (b.name == "acc_emit") return true;
    return false;
  };
  auto emission_buffers = [] {
    int n = 0;
    for (const auto& e : context().ledger().entries())
      n += e.name.find("acc_emit") != std::string::npos || e.name.find("out_emit") != std::string::npos;
    return n;
  };
  const int before = emission_buffers();
  render::Renderer r(context(), make_scene(j));
  r.add_samples(1);
  render::Image img = r.resolve();
  EXPECT_EQ(emission_buffers() - before, 0);
  EXPECT_FALSE(traces_emission(r));
  EXPECT_FALSE(img.surface_emission);
  for (const auto& [name, plane] : render::exr_planes(img))
    EXPECT_EQ(name.rfind("surface_emission", 0), std::string::npos);

  j["surfaces"].push_back({{"mesh", {{"kind", "box"}, {"size", {0.5, 0.5, 0.5}}}}, {"emission", {1, 1, 1}}});
  r.set_scene(make_scene(j), 1);
  r.add_samples(1);
  img = r.resolve();
  EXPECT_EQ(emission_buffers() - before, 2);
  EXPECT_TRUE(traces_emission(r));
  EXPECT_TRUE(img.surface_emission);
  EXPECT_EQ(context().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze::test
