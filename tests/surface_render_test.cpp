// Surfaces in the renderer: an emitting enclosure (closed form), motion vectors against independent CPU
// geometry, and depth gradients against finite differences. Same significance rule as estimator_test:
// alpha = 1e-4 two-sided, |z| < 3.89, fixed seeds.
#include <gtest/gtest.h>
#include <stb/stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <glm/gtc/matrix_transform.hpp>
#include <iostream>

#include "render/output.hpp"
#include "shaders/glsl.hpp"
#include "surfaces/embree_ref.hpp"
#include "surfaces/mesh.hpp"
#include "surfaces/texture.hpp"
#include "temp_dir.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using nlohmann::json;

// Inside a closed box whose walls all emit Le and reflect with albedo a, the radiance is Le / (1 - a)
// everywhere, also through a non-absorbing haze inside it (a furnace with surfaces), for both estimators.
// The haze keeps 0.25 off the walls: NEE from a medium vertex at distance h from an emitting wall weighs
// Le A cos / r^2, whose variance grows like 1/h^2, so haze up to the walls makes the estimator's variance
// infinite and its sample means heavy-tailed (z -5.6 for the default, volpath's sd of the mean 16x larger).
TEST(SurfaceRender, EmittingEnclosureIsAFurnace) {
  for (const char* estimator : {"default", "volpath"}) {
    SCOPED_TRACE(estimator);
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
                {"bounds_min", {-1.75, -1.25, -2.25}},
                {"bounds_max", {1.75, 1.25, 2.25}}}},
              {"render", {{"width", 8}, {"height", 8}, {"max_depth", 256}, {"estimator", estimator}}}};
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

// The G-buffer normal of pixel (x, y), decoded.
glm::dvec3 gbuffer_normal(const render::Image& img, int x, int y) {
  return glm::dvec3(
      glsl::oct_decode(glm::vec2(img.g(x, y, glsl::G_NORMAL), img.g(x, y, glsl::G_NORMAL + 1))));
}

double angle(glm::dvec3 a, glm::dvec3 b) {
  return std::acos(std::clamp(glm::dot(glm::normalize(a), glm::normalize(b)), -1.0, 1.0));
}

json sphere_scene(json mesh_or_file, json transform, int size) {
  json sf = {{"transform", transform}};
  if (mesh_or_file.is_string())
    sf["file"] = mesh_or_file;
  else
    sf["mesh"] = mesh_or_file;
  return {{"camera", {{"position", {0.4, 0.7, 3.2}}, {"target", {0, 0, 0}}, {"fov_y", 45}}},
          {"surfaces", {sf}},
          {"lights", {{"sun", {{"direction", {0.3, 1, 0.5}}}}}},
          {"render", {{"width", size}, {"height", size}, {"spp", 1}, {"pixel_jitter", false}}}};
}

// The G-buffer's normal layer holds the shading normal: on a coarse sphere turned and squashed by its
// transform, each pixel's normal is the hit triangle's vertex normals (through the inverse transpose)
// interpolated at the hit, with the triangle and barycentrics from Embree's intersector; on the round
// sphere it follows the analytic normal (X - centre) closely, where the flat triangles' normals do not.
// Injected defects caught: normals left in object space (the transformed sphere: max 31 degrees off),
// corners interpolated in v0, v2, v1 order (max 12 degrees), the G-buffer keeping the geometric normal
// (round sphere: mean error 3.6 degrees against 0.2).
TEST(SurfaceRender, SphereShadingNormalIsTheInterpolatedVertexNormal) {
  const json sphere = {{"kind", "sphere"}, {"radius", 1}, {"segments", 12}};
  {
    const json xf = {{"rotate", {20, 35, 0}}, {"scale", {1.2, 0.7, 1}}, {"translate", {0.1, 0, -0.2}}};
    scene::Scene s = make_scene(sphere_scene(sphere, xf, 64));
    render::Renderer r(context(), s);
    EXPECT_TRUE(r.has_feature("NORMALS"));
    r.add_samples(1);
    const render::Image img = r.resolve();
    const surfaces::Mesh mesh = surfaces::sphere(1, 12);
    const glm::dmat4 o2w(s.surfaces[0].transform.matrix());
    const glm::dmat3 nm = glm::transpose(glm::inverse(glm::dmat3(o2w)));
    surfaces::EmbreeScene embree(r.geometry().bvh.triangles);
    const std::vector<glm::dvec3> dirs = camera_directions(s);
    double worst = 0;
    int hits = 0;
    for (int y = 0; y < s.render.height; ++y)
      for (int x = 0; x < s.render.width; ++x) {
        const glm::dvec3 d = dirs[size_t(y) * s.render.width + x];
        surfaces::RefHit h = embree.intersect(s.camera.position, glm::vec3(d), 0, 1e30f);
        if (!h.hit()) continue;
        const glm::uvec3 c = mesh.triangles[h.primitive];
        glm::dvec3 n(0);
        const double w[3] = {1.0 - h.uv.x - h.uv.y, h.uv.x, h.uv.y};
        for (int i = 0; i < 3; ++i) n += w[i] * glm::normalize(nm * glm::dvec3(mesh.normals[c[i]]));
        // On the camera's side of the geometric normal (near the silhouette it may lean away from the
        // camera).
        if (glm::dot(n, glm::dvec3(h.normal)) * glm::dot(glm::dvec3(h.normal), d) > 0) n = -n;
        worst = std::max(worst, angle(gbuffer_normal(img, x, y), n));
        ++hits;
      }
    std::cout << "  transformed sphere: " << hits << " pixels, largest angle to the interpolated normal "
              << glm::degrees(worst) << " degrees\n";
    EXPECT_GT(hits, 800);
    EXPECT_LT(glm::degrees(worst), 0.01);  // measured 0.003 degrees
  }
  {
    scene::Scene s = make_scene(sphere_scene(sphere, json::object(), 64));
    render::Renderer r(context(), s);
    r.add_samples(1);
    const render::Image img = r.resolve();
    surfaces::EmbreeScene embree(r.geometry().bvh.triangles);
    const std::vector<glm::dvec3> dirs = camera_directions(s);
    double smooth_sum = 0, smooth_max = 0, flat_sum = 0;
    int hits = 0;
    for (int y = 0; y < s.render.height; ++y)
      for (int x = 0; x < s.render.width; ++x) {
        const glm::dvec3 d = dirs[size_t(y) * s.render.width + x];
        surfaces::RefHit h = embree.intersect(s.camera.position, glm::vec3(d), 0, 1e30f);
        if (!h.hit()) continue;
        const glm::dvec3 X = glm::dvec3(s.camera.position) + double(h.t) * d;
        const double e = angle(gbuffer_normal(img, x, y), X);
        smooth_sum += e;
        smooth_max = std::max(smooth_max, e);
        flat_sum += angle(glm::dvec3(h.normal), X);
        ++hits;
      }
    const double smooth_mean = glm::degrees(smooth_sum / hits), flat_mean = glm::degrees(flat_sum / hits);
    std::cout << "  round sphere, 12 segments: angle to the analytic normal, shading mean " << smooth_mean
              << " max " << glm::degrees(smooth_max) << " degrees; flat triangles mean " << flat_mean << "\n";
    // Position normals interpolate to the position: the shading normal at X is the analytic one up to the
    // 16-bit octahedral vertex normals (measured mean 0.0009, max 0.0017 degrees).
    EXPECT_LT(smooth_mean, 0.003);
    EXPECT_LT(glm::degrees(smooth_max), 0.005);
    EXPECT_GT(flat_mean, 5.0);
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// What the surface denoiser's normal tests see on a coarse sphere (8 segments: 45 degrees between facets):
// the filter's normal weight smoothstep(cos phi_n, 1, n.n') (phi_n = 30 degrees, filter.comp) and the
// reprojection test n.n' >= cos 37 degrees (accumulate.comp) between neighbouring pixels. With the
// primitive's vertex normals no neighbour pair looks like an edge; with the same mesh as an OBJ without
// normals (flat shading) the facet borders do. Pixels facing the camera within 60 degrees only (at the
// silhouette the sphere itself turns fast).
TEST(SurfaceRender, DenoiserNormalTestsStopSeeingFacets) {
  TempDir dir("haze_smooth");
  const surfaces::Mesh mesh = surfaces::sphere(1, 8);
  {
    std::ofstream obj(dir.path() / "faceted.obj");
    for (glm::vec3 p : mesh.positions) obj << "v " << p.x << " " << p.y << " " << p.z << "\n";
    for (glm::uvec3 t : mesh.triangles) obj << "f " << t.x + 1 << " " << t.y + 1 << " " << t.z + 1 << "\n";
  }
  const double cos_phi = std::cos(glm::radians(30.0)), cos_reproject = std::cos(glm::radians(37.0));
  auto edges = [&](json surface) {
    scene::Scene s = make_scene(sphere_scene(surface, json::object(), 96));
    render::Renderer r(context(), s);
    r.add_samples(1);
    const render::Image img = r.resolve();
    const std::vector<glm::dvec3> dirs = camera_directions(s);
    auto facing = [&](int x, int y) {
      return img.g(x, y, glsl::G_DEPTH) > 0 &&
             glm::dot(gbuffer_normal(img, x, y), -dirs[size_t(y) * s.render.width + x]) > 0.5;
    };
    int pairs = 0, weak = 0, rejected = 0;
    for (int y = 0; y + 1 < s.render.height; ++y)
      for (int x = 0; x + 1 < s.render.width; ++x) {
        if (!facing(x, y)) continue;
        for (glm::ivec2 o : {glm::ivec2(1, 0), glm::ivec2(0, 1)}) {
          if (!facing(x + o.x, y + o.y)) continue;
          const double c = glm::dot(gbuffer_normal(img, x, y), gbuffer_normal(img, x + o.x, y + o.y));
          const double t = std::clamp((c - cos_phi) / (1 - cos_phi), 0.0, 1.0);
          weak += t * t * (3 - 2 * t) < 0.5;
          rejected += c < cos_reproject;
          ++pairs;
        }
      }
    std::cout << "  " << (surface.is_string() ? "flat OBJ" : "smooth sphere") << ": " << pairs
              << " neighbour pairs, filter weight < 0.5: " << weak << ", reprojection rejects: " << rejected
              << "\n";
    EXPECT_GT(pairs, 5000);
    // A mesh without normals compiles no normal code and holds no normal buffer.
    EXPECT_EQ(r.has_feature("NORMALS"), !surface.is_string());
    int buffers = 0;
    for (const gpu::LedgerEntry& e : context().ledger().entries()) buffers += e.name == "triangle normals";
    EXPECT_EQ(buffers, surface.is_string() ? 0 : 1);
    return std::make_pair(weak, rejected);
  };
  auto smooth = edges({{"kind", "sphere"}, {"radius", 1}, {"segments", 8}});
  EXPECT_EQ(smooth.first, 0);
  EXPECT_EQ(smooth.second, 0);
  auto flat = edges((dir.path() / "faceted.obj").string());
  EXPECT_GT(flat.first, 100);
  EXPECT_GT(flat.second, 100);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// A square whose vertex normals lean 40 degrees towards +x, lit by a point-like sun grazing it from just
// below its plane (0.02 degrees under it, towards +x): the shading normal says lit, the geometry says the
// light is behind the surface, as at a coarse mesh's terminator. The camera above sees no light at all
// (nothing else lights the scene); the same sun 10 degrees above the surface lights it. Without the guard,
// shadow rays from within about 0.3 units of the +x border (where the grazing ray leaves the square before it
// crosses its plane, the origin being offset by 1e-4) reach the sun.
// Injected defect caught: NEE with the shading cosine alone (no geometric test): mean 0.033 instead of 0.
TEST(SurfaceRender, ShadingNormalsLeakNoLightThroughTheSurface) {
  TempDir dir("haze_leak");
  const glm::vec3 vn =
      glm::normalize(glm::vec3(std::sin(glm::radians(40.f)), std::cos(glm::radians(40.f)), 0));
  {
    std::ofstream obj(dir.path() / "leaning.obj");
    obj << "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\n";
    obj << "vn " << vn.x << " " << vn.y << " " << vn.z << "\n";
    obj << "f 1//1 4//1 3//1\nf 1//1 3//1 2//1\n";
  }
  auto render = [&](double sun_elevation) {
    const double e = glm::radians(sun_elevation);
    json j = {
        {"camera", {{"position", {0, 2, 0.01}}, {"target", {0, 0, 0}}, {"fov_y", 70}}},
        {"surfaces", {{{"file", (dir.path() / "leaning.obj").string()}, {"albedo", {0.8, 0.8, 0.8}}}}},
        {"lights",
         {{"sun",
           {{"direction", {std::cos(e), std::sin(e), 0}}, {"irradiance", 3}, {"angular_diameter", 0}}}}},
        {"render", {{"width", 16}, {"height", 16}, {"spp", 4}, {"max_depth", 3}}}};
    scene::Scene s = make_scene(j);
    render::Renderer r(context(), s);
    EXPECT_TRUE(r.has_feature("NORMALS"));
    r.add_samples(s.render.spp);
    const render::Image img = r.resolve();
    double sum = 0;
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) sum += img.at(x, y, glsl::OUT_SURF);
    return sum / (img.width * img.height);
  };
  const double below = render(-0.02), above = render(10);
  std::cout << "  mean red, sun 0.02 degrees below the surface " << below << ", 10 above " << above << "\n";
  EXPECT_EQ(below, 0.0);
  EXPECT_GT(above, 0.1);  // measured 0.30
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
