// The volume estimators on the GPU (lavapipe, real shaders) against closed forms and independent CPU
// integrals. Significance is fixed before looking at results: two-sided alpha = 1e-4 per test, |z| < 3.89,
// with the estimator's own per-pixel sample variance and fixed seeds.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "shaders/glsl.hpp"
#include "test_util.hpp"
#include "vdb/vdb.h"

namespace haze::test {
namespace {

constexpr double kZ = 3.89;
using glsl::ACC_L;
using glsl::ACC_L2;
using glsl::ACC_T;
using glsl::ACC_T2;
using nlohmann::json;

// Camera one unit below a slab y in [0, 1], looking up; rays cross only the slab's top and bottom faces.
json slab_camera(int size = 12) {
  return {{"camera", {{"position", {0, -1, 0}}, {"target", {0, 1, 0}}, {"up", {0, 0, 1}}, {"fov_y", 40}}},
          {"render", {{"width", size}, {"height", size}, {"pixel_jitter", false}, {"max_depth", 1}}}};
}

json haze_slab(double sigma, double albedo, double g) {
  return {{"sigma_t", sigma}, {"albedo", {albedo, albedo, albedo}}, {"g", g},
          {"bounded", true},  {"bounds_min", {-100, 0, -100}},      {"bounds_max", {100, 1, 100}}};
}

// A procedural constant box filling the slab; its trilinear profile along y is known exactly.
json box_medium(double scale, double albedo, double g) {
  return {{"procedural",
           {{"kind", "box"},
            {"voxel_size", 0.05},
            {"center", {0, 0.5, 0}},
            {"size", {8, 1, 8}},
            {"density", 1.0}}},
          {"density_scale", scale},
          {"albedo", {albedo, albedo, albedo}},
          {"g", g}};
}

// A constant box taller than the slab (by more than a voxel each side) clipped to it by media bounds: exactly
// the homogeneous slab, with no trilinear ramp at y = 0 and y = 1.
json bounded_box_medium(double scale, double albedo, double g) {
  json m = box_medium(scale, albedo, g);
  m["procedural"]["size"] = {8, 1.4, 8};
  m["bounds_min"] = {-100, 0, -100};
  m["bounds_max"] = {100, 1, 100};
  return m;
}

// A procedural cloud of diameter 2 at the origin, 0.08 voxels.
json cloud_medium(double density, int seed, const std::vector<double>& albedo, double g) {
  return {{"procedural",
           {{"kind", "cloud"},
            {"voxel_size", 0.08},
            {"center", {0, 0, 0}},
            {"size", {2, 2, 2}},
            {"density", density},
            {"seed", seed}}},
          {"albedo", albedo},
          {"g", g}};
}

// Density profile (in world y) of the box: 1 on the voxel centres it covers, linear to 0 over one voxel
// outside (trilinear interpolation), and its integral from -inf to y.
struct BoxProfile {
  double y0, y1, h;  // world y of the first and last voxel centre, voxel size
  double rho(double y) const {
    if (y <= y0 - h || y >= y1 + h) return 0;
    if (y < y0) return (y - (y0 - h)) / h;
    if (y > y1) return ((y1 + h) - y) / h;
    return 1;
  }
  double F(double y) const {
    double a = y0 - h;
    if (y <= a) return 0;
    if (y < y0) return 0.5 * (y - a) * (y - a) / h;
    double f = 0.5 * h;
    if (y <= y1) return f + (y - y0);
    f += y1 - y0;
    if (y < y1 + h) {
      double u = y - y1;
      return f + u - 0.5 * u * u / h;
    }
    return f + 0.5 * h;
  }
  double total() const { return F(y1 + 2 * h); }
};

BoxProfile box_profile(const render::Renderer& r) {
  const vdb::DeviceGrid& g = r.media().grids.at(0);
  EXPECT_FLOAT_EQ(g.value_min, 1.f);
  EXPECT_FLOAT_EQ(g.value_max, 1.f);
  glm::dvec4 a = g.index_to_world * glm::dvec4(0, g.index_min.y, 0, 1);
  glm::dvec4 b = g.index_to_world * glm::dvec4(0, g.index_max.y, 0, 1);
  glm::dvec4 c = g.index_to_world * glm::dvec4(0, g.index_min.y + 1, 0, 1);
  return {a.y, b.y, c.y - a.y};
}

TEST(Estimator, HomogeneousTransmittanceIsClosedForm) {
  json j = slab_camera();
  j["haze"] = haze_slab(1.3, 0.5, 0);
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(4);
  Estimate e = estimate(r, ACC_T, ACC_T2);
  auto dirs = camera_directions(s);
  for (size_t p = 0; p < dirs.size(); ++p) EXPECT_NEAR(e.mean[p], std::exp(-1.3 / dirs[p].y), 1e-5);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// A frame whose per-pixel data is far beyond lavapipe's 128 MiB maxStorageBufferRange (the accumulation alone
// would be 145 MB as one buffer): every layer is its own buffer within the limit, and every pixel, the last
// rows included, holds the closed-form transmittance.
TEST(Estimator, LargeFrameKeepsEveryBufferWithinTheDeviceRange) {
  json j = slab_camera();
  j["haze"] = haze_slab(1.3, 0.5, 0);
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  j["render"]["width"] = 1440;
  j["render"]["height"] = 810;
  scene::Scene s = make_scene(j);
  const auto before = context().ledger().per_category();
  render::Renderer r(context(), s);
  r.add_samples(1);
  render::Image img = r.resolve();
  const auto after = context().ledger().per_category();
  uint64_t per_pixel = 0;
  for (const char* c : {"per-frame temporaries", "outputs", "previous-frame data"})
    per_pixel += after.at(c) - (before.count(c) ? before.at(c) : 0);
  std::cout << "per-pixel data of a 1440x810 frame: " << per_pixel / 1048576.0 << " MiB\n";
  EXPECT_GT(per_pixel, 2 * context().limits().maxStorageBufferRange);
  for (const auto& e : context().ledger().entries())
    EXPECT_LE(e.requested, context().limits().maxStorageBufferRange) << e.name;
  auto dirs = camera_directions(s);
  double worst = 0;
  for (size_t p = 0; p < dirs.size(); ++p) {
    const double T = img.data[p * glsl::OUT_STRIDE + glsl::OUT_T];
    worst = std::max(worst, std::abs(T - std::exp(-1.3 / dirs[p].y)));
  }
  std::cout << "largest transmittance error " << worst << "\n";
  EXPECT_LT(worst, 4e-7);  // measured 1.3e-7
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(Estimator, RatioTrackingThroughVdbBox) {
  json j = slab_camera();
  j["media"] = {box_medium(1.5, 0.5, 0)};
  j["render"]["spp"] = 256;
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  BoxProfile b = box_profile(r);
  Estimate e = estimate(r, ACC_T, ACC_T2);
  auto dirs = camera_directions(s);
  std::vector<double> ref;
  for (auto d : dirs) ref.push_back(std::exp(-1.5 * b.total() / d.y));
  double z = z_score(e, ref);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  std::cout << "z = " << z << "\n";
  EXPECT_GT(e.var_of_mean[0], 0.0);  // really a stochastic estimate
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Single scattering of a vertical sun in a slab, seen from below. Reference: the 1D integral along each
// ray of sigma_s p E T_camera T_sun with the exact density profile.
double slab_single_scatter(glm::dvec3 d, double sigma, double albedo, double g, double E,
                           const std::function<double(double)>& rho, const std::function<double(double)>& F,
                           double F_total, double y_top) {
  double mu = d.y;  // wi = +y, deflection cosine dot(wi, d)
  double p = glsl::hg_phase(float(mu), float(g));
  double s_max = (y_top + 1.0) / d.y;
  return integrate(
      [&](double s) {
        double y = -1 + s * d.y;
        double tau_cam = sigma * F(y) / d.y;
        double tau_sun = sigma * (F_total - F(y));
        return sigma * rho(y) * albedo * p * E * std::exp(-tau_cam - tau_sun);
      },
      0, s_max, 4000);
}

// Distance guiding with probability P (guiding off for P < 0): every P must converge to the same image.
json guided(json j, double P) {
  if (P >= 0) j["guiding"] = {{"enabled", true}, {"probability", P}, {"spacing", 4}};
  return j;
}

// bounded: a VDB box clipped to the slab, against the homogeneous slab's reference.
void check_sunlit_slab(bool hetero, double p_equiangular, double guide_p = -1, bool bounded = false) {
  const double sigma = 0.8, albedo = 0.7, g = 0.4, E = 2.0;
  json j = slab_camera();
  if (bounded)
    j["media"] = {bounded_box_medium(sigma, albedo, g)};
  else if (hetero)
    j["media"] = {box_medium(sigma, albedo, g)};
  else
    j["haze"] = haze_slab(sigma, albedo, g);
  j["lights"] = {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", E}, {"angular_diameter", 0}}}};
  j["render"]["equiangular_probability"] = p_equiangular;
  j["render"]["volume_samples"] = 2;
  scene::Scene s = make_scene(guided(j, guide_p));
  render::Renderer r(context(), s);
  EXPECT_EQ(r.has_feature("GUIDING"), guide_p >= 0);
  r.add_samples(256);
  std::function<double(double)> rho, F;
  double total;
  double top = 1.0;
  BoxProfile b{};
  if (hetero && !bounded) {
    b = box_profile(r);
    rho = [&](double y) { return b.rho(y); };
    F = [&](double y) { return b.F(y); };
    total = b.total();
    top = b.y1 + b.h;
  } else {
    rho = [](double y) { return y >= 0 && y <= 1 ? 1.0 : 0.0; };
    F = [](double y) { return std::clamp(y, 0.0, 1.0); };
    total = 1.0;
  }
  auto dirs = camera_directions(s);
  std::vector<double> ref;
  for (auto d : dirs) ref.push_back(slab_single_scatter(d, sigma, albedo, g, E, rho, F, total, top));
  Estimate e = estimate(r, ACC_L, ACC_L2);
  double z = z_score(e, ref);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z << " mean[0] " << e.mean[0] << " ref[0] " << ref[0];
  std::cout << "z = " << z << "\n";
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(Estimator, SunlitHomogeneousSlabSingleScattering) {
  check_sunlit_slab(false, 0.5);
}
TEST(Estimator, SunlitVdbSlabSingleScattering) {
  check_sunlit_slab(true, 0.5);
}

// media[].bounds: a constant grid clipped to the slab is the homogeneous slab, in transmittance (ratio
// tracking, closed form) and in single scattering of the sun.
TEST(Estimator, BoundedVdbBoxIsTheHomogeneousSlab) {
  json j = slab_camera();
  j["media"] = {bounded_box_medium(1.5, 0.5, 0)};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  EXPECT_NEAR(r.media().majorant.world_min.y, 0.f, 1e-6);
  EXPECT_NEAR(r.media().majorant.world_max.y, 1.f, 1e-6);
  Estimate e = estimate(r, ACC_T, ACC_T2);
  auto dirs = camera_directions(s);
  std::vector<double> ref;
  for (auto d : dirs) ref.push_back(std::exp(-1.5 / d.y));
  double z = z_score(e, ref);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  std::cout << "z = " << z << "\n";
  EXPECT_EQ(context().validation_messages(), 0u);
  check_sunlit_slab(true, 0.5, -1, true);
}

// Airlight: an isotropic point light in unbounded homogeneous fog, single scattering. The reference is the
// equi-angular change of variables of the 1D integral (smooth, Simpson).
void check_airlight(double p_equiangular, double guide_p = -1) {
  const double sigma = 0.3, albedo = 0.8, g = 0.2, I = 5.0;
  const glm::dvec3 c(0.3, 0.2, 2.0), o(0, 0, 0);
  json j = {{"camera", {{"position", {0, 0, 0}}, {"target", {0, 0, 1}}, {"fov_y", 60}}},
            {"haze", {{"sigma_t", sigma}, {"albedo", {albedo, albedo, albedo}}, {"g", g}}},
            {"lights", {{"points", {{{"position", {c.x, c.y, c.z}}, {"intensity", I}}}}}},
            {"render",
             {{"width", 12},
              {"height", 12},
              {"pixel_jitter", false},
              {"max_depth", 1},
              {"equiangular_probability", p_equiangular}}}};
  scene::Scene s = make_scene(guided(j, guide_p));
  render::Renderer r(context(), s);
  r.add_samples(256);
  auto dirs = camera_directions(s);
  std::vector<double> ref;
  for (auto d : dirs) {
    double delta = glm::dot(c - o, d);
    double D = glm::length(c - (o + delta * d));
    double th_a = std::atan((0 - delta) / D), th_b = std::acos(0.0);
    ref.push_back(integrate(
        [&](double th) {
          double t = delta + D * std::tan(th);
          glm::dvec3 x = o + t * d;
          double r = glm::length(c - x);
          double mu = glm::dot((c - x) / r, d);
          double p = glsl::hg_phase(float(mu), float(g));
          return sigma * albedo * p * I * std::exp(-sigma * (t + r)) / D;
        },
        th_a, th_b - 1e-9, 20000));
  }
  Estimate e = estimate(r, ACC_L, ACC_L2);
  double z = z_score(e, ref);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z << " mean[0] " << e.mean[0] << " ref[0] " << ref[0];
  std::cout << "z = " << z << "\n";
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Guided distance sampling (the guide learns while it samples, from the first sample on).
class GuidedSlab : public ::testing::TestWithParam<double> {};
TEST_P(GuidedSlab, HomogeneousSunlitSlabIsUnbiased) {
  check_sunlit_slab(false, 0.5, GetParam());
}
TEST_P(GuidedSlab, VdbSunlitSlabIsUnbiased) {
  check_sunlit_slab(true, 0.5, GetParam());
}
TEST_P(GuidedSlab, AirlightWithEquiAngularIsUnbiased) {
  check_airlight(0.5, GetParam());
}
INSTANTIATE_TEST_SUITE_P(P, GuidedSlab, ::testing::Values(0.0, 0.5, 0.9));

// A heterogeneous cloud with multiple scattering, a sun and a point light has no closed form: the guided
// estimator must agree with the unguided one, each at a high sample count (two-sample z-test).
TEST_P(GuidedSlab, VdbCloudMatchesUnguided) {
  json j = {{"camera", {{"position", {0.3, 0.2, 3}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"media", json::array({cloud_medium(2.5, 3, {0.9, 0.8, 0.7}, 0.3)})},
            {"lights",
             {{"sun", {{"direction", {0.3, 1, 0.2}}, {"irradiance", 3}, {"angular_diameter", 0}}},
              {"points", {{{"position", {-0.5, 0.9, 0.4}}, {"intensity", 2}}}}}},
            {"render", {{"width", 10}, {"height", 10}, {"pixel_jitter", false}, {"max_depth", 3}}}};
  auto run = [&](double P) {
    scene::Scene s = make_scene(guided(j, P));
    render::Renderer r(context(), s);
    r.add_samples(768);
    return estimate(r, glsl::ACC_VOL, glsl::ACC_VOL2);
  };
  static const Estimate u = run(-1);  // shared by the three P
  Estimate g = run(GetParam());
  double diff = 0, var = 0;
  for (size_t p = 0; p < u.mean.size(); ++p) {
    diff += g.mean[p] - u.mean[p];
    var += g.var_of_mean[p] + u.var_of_mean[p];
  }
  double z = diff / std::sqrt(var);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  // P = 0 draws no guide candidates and learns nothing: exactly the unguided samples.
  if (GetParam() == 0) {
    EXPECT_EQ(diff, 0.0);
  }
  std::cout << "z = " << z << "\n";
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(Estimator, AirlightWithEquiAngularMis) {
  check_airlight(0.5);
}
TEST(Estimator, AirlightWithMajorantExponentialOnly) {
  check_airlight(0.0);
}

// White furnace: albedo 1 everywhere, uniform environment: every pixel sees exactly the environment,
// whatever the media (a cloud and overlapping haze, multiple scattering).
TEST(Estimator, WhiteFurnaceWithOverlappingMedia) {
  json j = {{"camera", {{"position", {0, 0, 4}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"media", json::array({cloud_medium(3.0, 5, {1, 1, 1}, 0.5)})},
            {"haze",
             {{"sigma_t", 0.7},
              {"albedo", {1, 1, 1}},
              {"g", -0.3},
              {"bounded", true},
              {"bounds_min", {-1, -1, -1}},
              {"bounds_max", {1, 1, 1}}}},
            {"lights", {{"environment", {{"color", {1, 1, 1}}, {"intensity", 1.0}}}}},
            {"render", {{"width", 10}, {"height", 10}, {"max_depth", 256}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(128);
  Estimate e = estimate(r, ACC_L, ACC_L2);
  double z = z_score(e, std::vector<double>(e.mean.size(), 1.0));
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  std::cout << "z = " << z << "\n";
  EXPECT_EQ(context().validation_messages(), 0u);
}

// GPU ratio-tracked transmittance through a procedural cloud against NanoVDB's CPU trilinear sampler,
// integrated along the same rays.
TEST(Estimator, GpuTransmittanceMatchesNanoVdbCpuSampler) {
  json j = {
      {"camera", {{"position", {0.2, 0.1, 3}}, {"target", {0, 0, 0}}, {"fov_y", 45}}},
      {"media",
       {{{"procedural",
          {{"kind", "cloud"},
           {"voxel_size", 0.06},
           {"center", {0, 0, 0}},
           {"size", {2, 2, 2}},
           {"density", 2.0},
           {"seed", 9}}},
         {"density_scale", 1.7},
         {"transform", {{"translate", {0.1, 0, 0}}, {"rotate", {0, 30, 10}}, {"scale", {1.2, 1, 1}}}}}}},
      {"render", {{"width", 10}, {"height", 10}, {"pixel_jitter", false}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  const auto& dm = r.media();
  const vdb::DeviceGrid& g = dm.grids.at(0);
  glm::dmat4 w2i = glm::inverse(glm::dmat4(s.media[0].transform.matrix()) * g.index_to_world);
  glm::dvec3 o(s.camera.position);
  vdb::Sampler sampler(g);
  std::vector<double> ref;
  for (auto d : camera_directions(s)) {
    double tau = 1.7 * integrate(
                           [&](double t) {
                             glm::dvec3 x = o + t * d;
                             return double(sampler.trilinear(glm::dvec3(w2i * glm::dvec4(x, 1))));
                           },
                           0, 8, 4000);
    ref.push_back(std::exp(-tau));
  }
  Estimate e = estimate(r, ACC_T, ACC_T2);
  double z = z_score(e, ref);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  std::cout << "z = " << z << "\n";
  EXPECT_EQ(context().validation_messages(), 0u);
}

// An absorbing, emitting slab (albedo 0, emission = scale * density): L = integral of sigma_a Le T along
// each ray, with the box's exact trilinear profile.
TEST(Estimator, AbsorbingEmittingVdbSlab) {
  const double sigma = 1.2, e_scale = 3.0;
  json j = slab_camera();
  json m = box_medium(sigma, 0.0, 0.0);
  m["emission"] = {{"mode", "scale"}, {"scale", e_scale}};
  j["media"] = {m};
  j["render"]["max_depth"] = 0;
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  BoxProfile b = box_profile(r);
  std::vector<double> ref;
  for (auto d : camera_directions(s)) {
    double s_max = (b.y1 + b.h + 1.0) / d.y;
    ref.push_back(integrate(
        [&](double t) {
          double y = -1 + t * d.y;
          return sigma * b.rho(y) * e_scale * b.rho(y) * std::exp(-sigma * b.F(y) / d.y);
        },
        0, s_max, 20000));
  }
  Estimate e = estimate(r, ACC_L, ACC_L2);
  double z = z_score(e, ref);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z << " mean[0] " << e.mean[0] << " ref[0] " << ref[0];
  std::cout << "z = " << z << "\n";
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Ratio tracking through a linearly varying medium: a ramp grid (trilinear interpolation is exact on it),
// so the optical depth is the integral of a known piecewise-linear profile.
TEST(Estimator, RatioTrackingThroughLinearRamp) {
  const double scale = 2.0, rho_top = 1.5;
  json j = slab_camera();
  j["media"] = {{{"procedural",
                  {{"kind", "ramp"},
                   {"voxel_size", 0.05},
                   {"center", {0, 0.5, 0}},
                   {"size", {8, 1, 8}},
                   {"density", rho_top}}},
                 {"density_scale", scale}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  const vdb::DeviceGrid& g = r.media().grids.at(0);
  double y0 = (g.index_to_world * glm::dvec4(0, g.index_min.y, 0, 1)).y;
  double y1 = (g.index_to_world * glm::dvec4(0, g.index_max.y, 0, 1)).y;
  double h = (g.index_to_world * glm::dvec4(0, g.index_min.y + 1, 0, 1)).y - y0;
  auto v = [&](double y) { return rho_top * y; };  // bottom face at y = 0, top at y = 1
  auto rho = [&](double y) {
    if (y <= y0 - h || y >= y1 + h) return 0.0;
    if (y < y0) return v(y0) * (y - (y0 - h)) / h;
    if (y > y1) return v(y1) * ((y1 + h) - y) / h;
    return v(y);
  };
  double tau_vertical = integrate(rho, y0 - h, y1 + h, 200000);
  std::vector<double> ref;
  for (auto d : camera_directions(s)) ref.push_back(std::exp(-scale * tau_vertical / d.y));
  Estimate e = estimate(r, ACC_T, ACC_T2);
  double z = z_score(e, ref);
  EXPECT_LT(std::abs(z), kZ) << "z = " << z;
  std::cout << "z = " << z << "\n";
  // The profile really is linear: the exact integral of rho_top * y over [0, 1] up to the voxel-edge terms.
  EXPECT_NEAR(tau_vertical, 0.5 * rho_top, 0.05 * rho_top);
  EXPECT_EQ(context().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze::test
