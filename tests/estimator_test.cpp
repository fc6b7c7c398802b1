// The volume estimators on the GPU (lavapipe, real shaders) against closed forms and independent CPU
// integrals, both estimators (render.estimator "default" and "volpath") through the same tests.
// Significance is fixed before looking at results: alpha = 1e-4 per test (test_util.hpp bias_test: per
// pixel and per channel, a chi-square of the z-scores and the pooled z of each channel, with the
// estimator's own per-pixel sample variance), fixed seeds. Every render must discard nothing (no
// non-finite sample, no step-cap abort, no majorant violation).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <glm/gtc/matrix_transform.hpp>
#include <iostream>
#include <random>

#include "bench/efficiency_bench.hpp"
#include "shaders/glsl.hpp"
#include "temp_dir.hpp"
#include "test_util.hpp"
#include "vdb/vdb.h"

namespace haze::test {
namespace {

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

// Haze filling the cube [-half, half]^3.
json haze_cube(double sigma_t, const std::vector<double>& albedo, double g, double half) {
  return {{"sigma_t", sigma_t},
          {"albedo", albedo},
          {"g", g},
          {"bounded", true},
          {"bounds_min", {-half, -half, -half}},
          {"bounds_max", {half, half, half}}};
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

// The estimators of every parametrised test below.
class EstimatorP : public ::testing::TestWithParam<std::string> {};
INSTANTIATE_TEST_SUITE_P(Estimators, EstimatorP, ::testing::Values("default", "volpath"));

json with_estimator(json j, const std::string& estimator) {
  j["render"]["estimator"] = estimator;
  return j;
}

// The default estimator's transmittance through homogeneous haze is its closed form (the haze is the
// control of residual ratio tracking): the same value in every sample.
TEST(Estimator, HomogeneousTransmittanceIsClosedForm) {
  json j = slab_camera();
  j["haze"] = haze_slab(1.3, 0.5, 0);
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 4, "haze transmittance");
  Estimate e = estimate(r, ACC_T, ACC_T2);
  auto dirs = camera_directions(s);
  for (size_t p = 0; p < dirs.size(); ++p) EXPECT_NEAR(e.mean[p], std::exp(-1.3 / dirs[p].y), 1e-5);
}

// volpath tracks the haze like any medium (pbrt-v4 has no control variate): T is delta tracking's 0/1.
TEST(Estimator, VolpathTransmittanceThroughHazeIsUnbiased) {
  json j = with_estimator(slab_camera(), "volpath");
  j["haze"] = haze_slab(1.3, 0.5, 0);
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 256, "volpath haze transmittance");
  std::vector<double> ref;
  for (auto d : camera_directions(s)) ref.push_back(std::exp(-1.3 / d.y));
  Estimate e = estimate(r, ACC_T, ACC_T2);
  expect_unbiased(bias_test(e, ref), "volpath T");
  EXPECT_GT(e.var_of_mean[0], 0.0);
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
  expect_no_discards(img.counters, "large frame");
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

TEST_P(EstimatorP, RatioTrackingThroughVdbBox) {
  json j = with_estimator(slab_camera(), GetParam());
  j["media"] = json::array({box_medium(1.5, 0.5, 0)});
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 256, "vdb box");
  BoxProfile b = box_profile(r);
  Estimate e = estimate(r, ACC_T, ACC_T2);
  std::vector<double> ref;
  for (auto d : camera_directions(s)) ref.push_back(std::exp(-1.5 * b.total() / d.y));
  expect_unbiased(bias_test(e, ref), "T through a VDB box");
  EXPECT_GT(e.var_of_mean[0], 0.0);  // really a stochastic estimate
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

// Distance guiding with probability P everywhere (guiding off for P < 0) and the guide `model`: every P must
// converge to the same image.
json guided(json j, double P, const std::string& model = "histogram") {
  if (P >= 0)
    j["guiding"] = {{"enabled", true},
                    {"probability", P},
                    {"spacing", 4},
                    {"model", model},
                    {"choose_probability", false}};
  return j;
}

// Guiding happened as asked: with P > 0 the guide drew most of its share P of the distance samples (its
// mixture was usable for nearly every sample), with P = 0 none.
void expect_guided_share(const render::FrameCounters& c, double P) {
  ASSERT_GT(c.distance_samples, 0u);
  const double share = double(c.guided) / double(c.distance_samples);
  std::cout << "guided share " << share << " at P = " << P << "\n";
  if (P == 0) {
    EXPECT_EQ(c.guided, 0u);
  } else {
    EXPECT_GT(share, 0.9 * P);
    EXPECT_LT(share, P + 4 * std::sqrt(P * (1 - P) / double(c.distance_samples)));
  }
}

struct SlabCase {
  std::string estimator = "default";
  bool hetero = false;
  double p_equiangular = 0.5;
  double guide_p = -1;
  bool bounded = false;  // a VDB box clipped to the slab, against the homogeneous slab's reference
  double sigma = 0.8;
  bool delta_tracked = false;  // the camera rays are delta-tracked: no sample may be guided
  std::string guide_model = "histogram";
};

void check_sunlit_slab(const SlabCase& c) {
  const double sigma = c.sigma, albedo = 0.7, g = 0.4, E = 2.0;
  json j = with_estimator(slab_camera(), c.estimator);
  if (c.bounded)
    j["media"] = json::array({bounded_box_medium(sigma, albedo, g)});
  else if (c.hetero)
    j["media"] = json::array({box_medium(sigma, albedo, g)});
  else
    j["haze"] = haze_slab(sigma, albedo, g);
  j["lights"] = {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", E}, {"angular_diameter", 0}}}};
  j["render"]["equiangular_probability"] = c.p_equiangular;
  j["render"]["volume_samples"] = 2;
  scene::Scene s = make_scene(guided(j, c.guide_p, c.guide_model));
  render::Renderer r(context(), s);
  EXPECT_EQ(r.has_feature("GUIDING"), c.guide_p >= 0);
  EXPECT_EQ(r.has_feature("GUIDE_HIST"), c.guide_p >= 0 && c.guide_model == "histogram");
  render::Image img = render_checked(r, 256, "sunlit slab");
  if (c.guide_p >= 0) expect_guided_share(img.counters, c.delta_tracked ? 0.0 : c.guide_p);
  std::function<double(double)> rho, F;
  double total;
  double top = 1.0;
  BoxProfile b{};
  if (c.hetero && !c.bounded) {
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
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), ref), "sunlit slab, " + c.estimator);
}

// Injected into volpath: the scattering throughput multiplied by the albedo without dividing by the
// probability of scattering (mean albedo): pooled z -49.
TEST_P(EstimatorP, SunlitHomogeneousSlabSingleScattering) {
  check_sunlit_slab({GetParam(), false});
}
// Injected into the default: delta-tracked camera samples weighted 1 instead of 1/N (N = 2): pooled z 105.
TEST_P(EstimatorP, SunlitVdbSlabSingleScattering) {
  check_sunlit_slab({GetParam(), true});
}

// media[].bounds: a constant grid clipped to the slab is the homogeneous slab, in transmittance (ratio
// tracking, closed form) and in single scattering of the sun.
TEST_P(EstimatorP, BoundedVdbBoxIsTheHomogeneousSlab) {
  json j = with_estimator(slab_camera(), GetParam());
  j["media"] = json::array({bounded_box_medium(1.5, 0.5, 0)});
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 256, "bounded box");
  EXPECT_NEAR(r.media().majorant.world_min.y, 0.f, 1e-6);
  EXPECT_NEAR(r.media().majorant.world_max.y, 1.f, 1e-6);
  Estimate e = estimate(r, ACC_T, ACC_T2);
  std::vector<double> ref;
  for (auto d : camera_directions(s)) ref.push_back(std::exp(-1.5 / d.y));
  expect_unbiased(bias_test(e, ref), "T through a bounded box");
  check_sunlit_slab({GetParam(), true, 0.5, -1, true});
}

// Airlight: an isotropic point light in unbounded homogeneous fog, single scattering. The reference is the
// equi-angular change of variables of the 1D integral (smooth, Simpson).
void check_airlight(const std::string& estimator, double p_equiangular, double guide_p = -1,
                    const std::string& guide_model = "histogram") {
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
  scene::Scene s = make_scene(guided(with_estimator(j, estimator), guide_p, guide_model));
  render::Renderer r(context(), s);
  render::Image img = render_checked(r, 256, "airlight");
  if (guide_p >= 0) expect_guided_share(img.counters, guide_p);
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
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), ref), "airlight, " + estimator);
}

// Guided distance sampling (the guide learns while it samples, from the first sample on), with the
// histogram guide at P 0, 0.5 and 0.9 and the Gaussian states at 0.5.
// Injected into the histogram guide at P 0.5, homogeneous slab: its pdf not renormalised to the ray's part
// [0, t_end] (the total over [0, R] instead): pooled z 4.55 against the critical 4.31 (fails); the mixture
// without the 1 - P of q_rest: pooled z -403.
struct GuidedSlabCase {
  std::string model;
  double P;
};
void PrintTo(const GuidedSlabCase& c, std::ostream* os) {
  *os << c.model << " P " << c.P;
}
class GuidedSlab : public ::testing::TestWithParam<GuidedSlabCase> {};
SlabCase guided_slab(bool hetero, double sigma = 0.8) {
  SlabCase c{"default", hetero, 0.5, GuidedSlab::GetParam().P, false, sigma};
  c.guide_model = GuidedSlab::GetParam().model;
  return c;
}
TEST_P(GuidedSlab, HomogeneousSunlitSlabIsUnbiased) {
  check_sunlit_slab(guided_slab(false));
}
// Thin enough (majorant optical depth below 0.1 on every ray) that the camera rays are not delta-tracked,
// which would leave them unguided.
TEST_P(GuidedSlab, VdbSunlitSlabIsUnbiased) {
  check_sunlit_slab(guided_slab(true, 0.04));
}
TEST_P(GuidedSlab, AirlightWithEquiAngularIsUnbiased) {
  check_airlight("default", 0.5, GetParam().P, GetParam().model);
}
// Camera rays through a heterogeneous majorant optical depth of 0.1 or more are delta-tracked and not
// guided, whatever P (docs/guiding.md), and stay unbiased. Injected: a P_guide that ignores delta_cam gave
// guided shares of 0.50 and 0.90 at P 0.5 and 0.9 (fails).
TEST_P(GuidedSlab, DenseVdbRaysAreDeltaTrackedNotGuided) {
  SlabCase c = guided_slab(true);
  c.delta_tracked = true;
  check_sunlit_slab(c);
}
INSTANTIATE_TEST_SUITE_P(P, GuidedSlab,
                         ::testing::Values(GuidedSlabCase{"histogram", 0.0}, GuidedSlabCase{"histogram", 0.5},
                                           GuidedSlabCase{"histogram", 0.9}, GuidedSlabCase{"gaussian", 0.5}),
                         [](const ::testing::TestParamInfo<GuidedSlabCase>& i) {
                           return i.param.model + "_P" + std::to_string(int(std::lround(i.param.P * 100)));
                         });

// A heterogeneous cloud with multiple scattering, a sun and a point light has no closed form: the guided
// estimator must agree with the unguided one, each at a high sample count (two-sample test per pixel and
// channel).
TEST_P(GuidedSlab, VdbCloudMatchesUnguided) {
  json j = {{"camera", {{"position", {0.3, 0.2, 3}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"media", json::array({cloud_medium(2.5, 3, {0.9, 0.8, 0.7}, 0.3)})},
            {"lights",
             {{"sun", {{"direction", {0.3, 1, 0.2}}, {"irradiance", 3}, {"angular_diameter", 0}}},
              {"points", {{{"position", {-0.5, 0.9, 0.4}}, {"intensity", 2}}}}}},
            {"render", {{"width", 10}, {"height", 10}, {"pixel_jitter", false}, {"max_depth", 3}}}};
  auto run = [&](double P) {
    // Guided runs with P > 0 take another seed than the unguided one: with the same seed the two share
    // their camera samples and unguided choices, and the two-sample test, which assumes independent
    // estimates, loses power. P = 0 keeps the seed for the comparison below.
    json k = guided(j, P, GetParam().model);
    k["render"]["seed"] = P > 0 ? 2 : 1;
    scene::Scene s = make_scene(k);
    render::Renderer r(context(), s);
    render::Image img = render_checked(r, 768, "cloud");
    if (P >= 0) expect_guided_share(img.counters, P);
    return estimate(r, glsl::ACC_VOL, glsl::ACC_VOL2, 3);
  };
  static const Estimate u = run(-1);  // shared by the cases
  Estimate g = run(GetParam().P);
  expect_unbiased(two_sample_test(g, u), "guided against unguided");
  if (GetParam().P == 0) {
    // P = 0 draws no guide candidates and learns nothing: the unguided samples, in another permutation
    // (GUIDING), whose compiled float arithmetic may differ in rounding.
    double worst = 0;
    for (size_t i = 0; i < u.mean.size(); ++i)
      worst = std::max(worst, std::abs(g.mean[i] - u.mean[i]) / std::max(std::abs(u.mean[i]), 1e-6));
    std::cout << "P = 0 against unguided: largest relative difference " << worst << "\n";
    EXPECT_LT(worst, 1e-5);
  }
}

// Injected: the equi-angular pdf scaled by 0.9 in q (one strategy's 1/q off by a tenth): pooled z 9.8,
// chi-square 383 against 226.
TEST(Estimator, AirlightWithEquiAngularMis) {
  check_airlight("default", 0.5);
}
TEST(Estimator, AirlightWithMajorantExponentialOnly) {
  check_airlight("default", 0.0);
}
TEST(Estimator, AirlightWithEquiAngularOnly) {
  check_airlight("default", 1.0);
}
TEST(Estimator, VolpathAirlight) {
  check_airlight("volpath", 0.5);
}

// A spot light in unbounded homogeneous fog, single scattering: equi-angular sampling clipped to the spot's
// cone (shaders/common/sampling.glsl cone_clip) against the 1D quadrature along each camera ray of
// sigma_s p I falloff / r^2 exp(-sigma (t + r)), the falloff the shader's smoothstep. Some pixels' rays cross
// the cone, others pass beside it. Prints the mean relative standard error over the lit pixels (the figure
// of docs/benchmarks.md, "Spot cones").
// Injected: the pdf evaluated over the unclipped [0, t_s] while the sample is drawn on the clipped segment:
// pooled z +48 (p_ea 0.5) and +134 (p_ea 0.95).
void check_spot_airlight(double p_equiangular) {
  const double sigma = 0.3, albedo = 0.8, g = 0.2, I = 5.0, cone = 20.0, falloff = 5.0;
  const glm::dvec3 c(0.3, 1.5, 2.0), axis(0, -1, 0), o(0, 0, 0);
  json j = {{"camera", {{"position", {0, 0, 0}}, {"target", {0, 0, 1}}, {"fov_y", 60}}},
            {"haze", {{"sigma_t", sigma}, {"albedo", {albedo, albedo, albedo}}, {"g", g}}},
            {"lights",
             {{"spots",
               {{{"position", {c.x, c.y, c.z}},
                 {"direction", {axis.x, axis.y, axis.z}},
                 {"intensity", I},
                 {"cone_angle", cone},
                 {"falloff_angle", falloff}}}}}},
            {"render",
             {{"width", 12},
              {"height", 12},
              {"pixel_jitter", false},
              {"max_depth", 1},
              {"equiangular_probability", p_equiangular}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 256, "spot airlight");
  const double cos_outer = std::cos(glm::radians(cone)), cos_inner = std::cos(glm::radians(cone - falloff));
  auto smooth = [](double e0, double e1, double x) {
    double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
    return t * t * (3 - 2 * t);
  };
  std::vector<double> ref;
  for (auto d : camera_directions(s)) {
    ref.push_back(integrate(
        [&](double t) {
          glm::dvec3 x = o + t * d;
          double r = glm::length(c - x);
          double mu = glm::dot((c - x) / r, d);
          double p = glsl::hg_phase(float(mu), float(g));
          double f = smooth(cos_outer, cos_inner, glm::dot((x - c) / r, axis));
          return sigma * albedo * p * I * f * std::exp(-sigma * (t + r)) / (r * r);
        },
        0, 60, 60000));
  }
  Estimate e = estimate(r, ACC_L, ACC_L2, 3);
  double rel = 0;
  int lit = 0;
  for (size_t p = 0; p < ref.size(); ++p)
    if (ref[p] > 1e-4) {
      rel += std::sqrt(e.var_of_mean[p * 3]) / ref[p];
      ++lit;
    }
  // Rays that miss the cone see nothing, exactly; they are left out of the statistics (no variance to test).
  for (size_t p = 0; p < ref.size(); ++p)
    if (ref[p] == 0) {
      for (int k = 0; k < 3; ++k) EXPECT_EQ(e.mean[p * 3 + k], 0.0) << "pixel " << p;
      ref[p] = std::nan("");
    }
  std::cout << "spot airlight, p_ea " << p_equiangular << ": " << lit
            << " lit pixels, mean relative standard "
            << "error " << rel / lit << " at 256 samples\n";
  expect_unbiased(bias_test(e, ref), "spot airlight");
}
TEST(Estimator, SpotAirlightWithConeClippedEquiAngular) {
  check_spot_airlight(0.5);
}
TEST(Estimator, SpotAirlightWithConeClippedEquiAngularOnly) {
  check_spot_airlight(0.95);
}

// White furnace: albedo 1 everywhere, uniform environment: every pixel sees exactly the environment,
// whatever the media (a cloud and overlapping haze, multiple scattering).
TEST_P(EstimatorP, WhiteFurnaceWithOverlappingMedia) {
  json j = {{"camera", {{"position", {0, 0, 4}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"media", json::array({cloud_medium(3.0, 5, {1, 1, 1}, 0.5)})},
            {"haze", haze_cube(0.7, {1, 1, 1}, -0.3, 1)},
            {"lights", {{"environment", {{"color", {1, 1, 1}}, {"intensity", 1.0}}}}},
            {"render", {{"width", 10}, {"height", 10}, {"max_depth", 256}}}};
  scene::Scene s = make_scene(with_estimator(j, GetParam()));
  render::Renderer r(context(), s);
  render_checked(r, 128, "white furnace");
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), std::vector<double>(100, 1.0)), "white furnace");
}

// An emitting furnace: inside a medium much thicker than a mean free path in every direction, with albedo a
// and emission L_e everywhere, radiative equilibrium makes the radiance L_e in every direction
// (L = (1 - a) L_e + a L). Paths of up to 256 events with a = 0.9 leave 0.9^257 ~ 2e-12 out, the box's walls
// (optical depth 20 away) e^-20. The walk's roulette works hard here (the throughput falls below a quarter
// after 13 events). Injected: the default walk's roulette survivors not reweighted: pooled z -481 (the
// white furnace above, albedo 1, never triggers that roulette).
TEST_P(EstimatorP, EmittingFurnace) {
  json j = {{"camera", {{"position", {0, 0, 0}}, {"target", {0.3, 0.2, 1}}, {"fov_y", 90}}},
            {"media",
             {{{"procedural",
                {{"kind", "box"},
                 {"voxel_size", 1.0},
                 {"center", {0, 0, 0}},
                 {"size", {40, 40, 40}},
                 {"density", 1.0}}},
               {"albedo", {0.9, 0.9, 0.9}},
               {"g", 0.3},
               {"emission", {{"mode", "scale"}, {"scale", 2.0}}}}}},
            {"render", {{"width", 6}, {"height", 6}, {"max_depth", 256}}}};
  scene::Scene s = make_scene(with_estimator(j, GetParam()));
  render::Renderer r(context(), s);
  render_checked(r, 256, "emitting furnace");
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), std::vector<double>(36, 2.0)), "emitting furnace");
}

// A Lambertian furnace: inside a closed sphere whose surface has albedo a and emission E, with max_depth D,
// every pixel sees E (1 + a + ... + a^D): E directly, and each event's NEE to the emitting surface brings
// back a E (its irradiance is pi E everywhere inside). Surface bounces and both estimators' roulettes at
// surfaces. A sphere, not a box: between two points of a sphere cos cos / r^2 is constant, while a box's
// edges make NEE by area heavy-tailed (1 / r^2 near an edge), too heavy for a normal z per pixel (chi-square
// 2-3 times its degrees of freedom, pooled z fine). Injected into volpath: its surface roulette survivors not
// divided by their survival probability: pooled z -78.
TEST_P(EstimatorP, LambertianFurnace) {
  const double a = 0.5, E = 1.5;
  const int D = 8;
  json j = {{"camera", {{"position", {0.2, -0.3, 0.1}}, {"target", {1, 0.3, 0.6}}, {"fov_y", 90}}},
            {"surfaces",
             {{{"mesh", {{"kind", "sphere"}, {"radius", 1.5}, {"segments", 48}}},
               {"albedo", {a, a, a}},
               {"emission", {E, E, E}}}}},
            {"render", {{"width", 6}, {"height", 6}, {"max_depth", D}}}};
  scene::Scene s = make_scene(with_estimator(j, GetParam()));
  render::Renderer r(context(), s);
  render_checked(r, 256, "lambertian furnace");
  const double ref = E * (1 - std::pow(a, D + 1)) / (1 - a);
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), std::vector<double>(36, ref)),
                  "lambertian furnace");
}

// GPU ratio-tracked transmittance through a procedural cloud against NanoVDB's CPU trilinear sampler,
// integrated along the same rays.
TEST_P(EstimatorP, GpuTransmittanceMatchesNanoVdbCpuSampler) {
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
  scene::Scene s = make_scene(with_estimator(j, GetParam()));
  render::Renderer r(context(), s);
  // Ratio tracking's roulette makes T in the cloud's core a few rare large values: 1024 samples give
  // nearly every pixel enough of them for a normal z.
  render_checked(r, 1024, "cloud transmittance");
  const auto& dm = r.media();
  // The default estimator's ratio tracking takes the minorant grid's part of the optical depth in closed
  // form (its control); volpath, plain ratio tracking, holds no minorant grid.
  const bool minorant = GetParam() == "default";
  EXPECT_EQ(r.has_feature("MINORANT"), minorant);
  // And it reads one voxel a lookup, chosen by the trilinear weights, through one accessor per sample: the
  // CPU reference below is trilinear. Injected: the corner's x never 1 (floor on x) gives chi-square 1273
  // against 130, pooled z +7.4 (and ShadowRaysThroughCloudMatchNanoVdbCpuSampler 2080 against 226).
  EXPECT_EQ(r.has_feature("STOCHASTIC_LOOKUP"), minorant);
  EXPECT_EQ(r.has_feature("ONE_GRID"), minorant);
  // One grid of bounds: the minorant grid's pairs hold the majorants, so it replaces the majorant grid.
  int minorant_buffers = 0, majorant_buffers = 0;
  for (const auto& e : context().ledger().entries()) {
    minorant_buffers += e.name == "minorant grid";
    majorant_buffers += e.name == "majorant grid";
  }
  EXPECT_EQ(minorant_buffers, minorant ? 1 : 0);
  EXPECT_EQ(majorant_buffers, minorant ? 0 : 1);
  double sum_min = 0, sum_max = 0;
  for (size_t i = 0; i < dm.majorant.sigma_max.size(); ++i) {
    sum_min += dm.majorant.sigma_min[i];
    sum_max += dm.majorant.sigma_max[i];
  }
  std::cout << "minorant / majorant, summed over cells: " << sum_min / sum_max << "\n";
  EXPECT_GT(sum_min, 0.2 * sum_max);
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
  // Rays that graze the cloud see an optical depth of about 1e-3: ratio tracking may meet no null collision
  // on them in all 1024 samples (T = 1 every time, no variance; pixel 97 here, reference 0.9986), so a value
  // without variance is held to 4e-3 rather than the default 1e-3.
  expect_unbiased(bias_test(estimate(r, ACC_T, ACC_T2), ref, kAlpha, 4e-3),
                  "T against NanoVDB's CPU sampler");
}

// A grid with a negative voxel: the shader counts a negative density as 0, which does not commute with
// choosing one voxel of the eight, so the default estimator reads it trilinearly and says so in a note.
TEST(Estimator, NegativeGridValuesKeepTrilinearLookups) {
  test::TempDir dir("haze_negative_grid");
  vdb::VoxelGrid g;
  g.index_to_world = glm::scale(glm::dmat4(1), glm::dvec3(0.1));
  g.boxes.push_back({glm::ivec3(-5), glm::ivec3(5), 1.f});
  const std::string file = (dir.path() / "neg.vdb").string();
  for (float v : {0.5f, -0.25f}) {
    g.voxels = {{glm::ivec3(0), v}};
    vdb::write_grids({g}, file);
    json j = {{"camera", {{"position", {0, 0, 3}}, {"target", {0, 0, 0}}, {"fov_y", 30}}},
              {"media", {{{"file", file}}}},
              {"render", {{"width", 4}, {"height", 4}}}};
    render::Renderer r(context(), make_scene(j));
    const auto notes = r.notes();
    const auto said = std::count_if(notes.begin(), notes.end(), [](const std::string& n) {
      return n.find("media[0]: the grid has negative values (down to -0.25)") != std::string::npos;
    });
    EXPECT_EQ(said, v < 0 ? 1 : 0) << v;
    EXPECT_EQ(r.has_feature("STOCHASTIC_LOOKUP"), v > 0) << v;
    EXPECT_TRUE(r.has_feature("MINORANT"));
  }
}

// An absorbing, emitting slab (albedo 0, emission = scale * density): L = integral of sigma_a Le T along
// each ray, with the box's exact trilinear profile.
TEST_P(EstimatorP, AbsorbingEmittingVdbSlab) {
  const double sigma = 1.2, e_scale = 3.0;
  json j = with_estimator(slab_camera(), GetParam());
  json m = box_medium(sigma, 0.0, 0.0);
  m["emission"] = {{"mode", "scale"}, {"scale", e_scale}};
  j["media"] = json::array({m});
  j["render"]["max_depth"] = 0;
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 256, "emitting slab");
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
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), ref), "emitting slab");
}

// Ratio tracking through a linearly varying medium: a ramp grid (trilinear interpolation is exact on it),
// so the optical depth is the integral of a known piecewise-linear profile. The default estimator
// delta-tracks these camera rays as decomposition tracking (the minorant's collisions need no lookup).
// Injected: the control taken as 1.5 times the minorant: pooled z -8.3.
void check_ramp(const std::string& estimator, double scale, int spp) {
  const double rho_top = 1.5;
  json j = with_estimator(slab_camera(), estimator);
  j["media"] = {{{"procedural",
                  {{"kind", "ramp"},
                   {"voxel_size", 0.05},
                   {"center", {0, 0.5, 0}},
                   {"size", {8, 1, 8}},
                   {"density", rho_top}}},
                 {"density_scale", scale}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  EXPECT_EQ(r.has_feature("DECOMPOSITION"), estimator == "default");
  render_checked(r, spp, "ramp");
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
  expect_unbiased(bias_test(estimate(r, ACC_T, ACC_T2), ref), "T through a ramp");
  // The profile really is linear: the exact integral of rho_top * y over [0, 1] up to the voxel-edge terms.
  EXPECT_NEAR(tau_vertical, 0.5 * rho_top, 0.05 * rho_top);
}

TEST_P(EstimatorP, RatioTrackingThroughLinearRamp) {
  check_ramp(GetParam(), 2.0, 256);
}

// Shadow rays by ratio tracking through a dense ramp (optical depth about 4.5 straight up, T about 0.01,
// where the roulette decides most of the estimate): a floor below the ramp, lit by the sun from straight
// above and seen from under the ramp, has L = albedo / pi E T. The camera's rays meet no medium.
TEST_P(EstimatorP, ShadowRaysThroughDenseRamp) {
  const double scale = 6.0, rho_top = 1.5, albedo = 0.8, E = 3.0;
  json j = with_estimator(slab_camera(), GetParam());
  j["camera"] = {{"position", {0, -0.2, 0}}, {"target", {0, -1, 0.2}}, {"up", {0, 0, 1}}, {"fov_y", 40}};
  j["media"] = {{{"procedural",
                  {{"kind", "ramp"},
                   {"voxel_size", 0.05},
                   {"center", {0, 0.5, 0}},
                   {"size", {8, 1, 8}},
                   {"density", rho_top}}},
                 {"density_scale", scale}}};
  j["surfaces"] = {{{"mesh", {{"kind", "plane"}, {"size", {20, 20}}}},
                    {"transform", {{"translate", {0, -0.5, 0}}, {"rotate", {-90, 0, 0}}}},
                    {"albedo", {albedo, albedo, albedo}}}};
  j["lights"] = {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", E}, {"angular_diameter", 0}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  // The roulette makes T a few rare large values: volpath's (survival 1/4 below 0.05) needs about 4096
  // samples per pixel before its per-pixel z is normal (chi-square over its critical value at 1024).
  render_checked(r, 4096, "shadow rays through a ramp");
  const vdb::DeviceGrid& g = r.media().grids.at(0);
  double y0 = (g.index_to_world * glm::dvec4(0, g.index_min.y, 0, 1)).y;
  double y1 = (g.index_to_world * glm::dvec4(0, g.index_max.y, 0, 1)).y;
  double h = (g.index_to_world * glm::dvec4(0, g.index_min.y + 1, 0, 1)).y - y0;
  auto rho = [&](double y) {
    if (y <= y0 - h || y >= y1 + h) return 0.0;
    if (y < y0) return rho_top * y0 * (y - (y0 - h)) / h;
    if (y > y1) return rho_top * y1 * ((y1 + h) - y) / h;
    return rho_top * y;
  };
  const double T = std::exp(-scale * integrate(rho, y0 - h, y1 + h, 200000));
  std::cout << "T through the ramp " << T << "\n";
  // Injected: ratio tracking's roulette survivors not divided by their survival probability: pooled z
  // -27 (default) and -18 (volpath).
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), std::vector<double>(144, albedo / M_PI * E * T)),
                  "floor lit through a ramp");
}

// Shadow rays through a rotated, scaled procedural cloud against NanoVDB's CPU sampler: a floor under the
// cloud, lit by the sun from straight above and seen from below the cloud, has L = albedo / pi E T(sun ray),
// with T from the CPU optical depth on the vertical through each pixel's floor point. The default
// estimator's shadow rays take the minorant grid's part of that depth in closed form (and its roulette on
// the control, down to T of 6e-3 here); volpath tracks all of it.
// Injected: the first segment with a minorant left out of the control's exp(-tau) (default): pooled z +4.77
// (critical 4.31; that segment is at the cloud's thin edge). ShadowRaysThroughDenseRamp: +110.8.
TEST_P(EstimatorP, ShadowRaysThroughCloudMatchNanoVdbCpuSampler) {
  const double scale = 1.7, albedo = 0.8, E = 3.0;
  json j = with_estimator(slab_camera(), GetParam());
  j["camera"] = {{"position", {0, -0.1, 0}}, {"target", {0.1, -1, 0.2}}, {"up", {0, 0, 1}}, {"fov_y", 40}};
  j["media"] = {
      {{"procedural",
        {{"kind", "cloud"},
         {"voxel_size", 0.06},
         {"center", {0, 0, 0}},
         {"size", {2, 2, 2}},
         {"density", 2.0},
         {"seed", 9}}},
       {"density_scale", scale},
       {"transform", {{"translate", {0, 1.8, 0}}, {"rotate", {0, 30, 10}}, {"scale", {1.2, 1, 1}}}}}};
  j["surfaces"] = {{{"mesh", {{"kind", "plane"}, {"size", {20, 20}}}},
                    {"transform", {{"translate", {0, -1, 0}}, {"rotate", {-90, 0, 0}}}},
                    {"albedo", {albedo, albedo, albedo}}}};
  j["lights"] = {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", E}, {"angular_diameter", 0}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  EXPECT_EQ(r.has_feature("MINORANT"), GetParam() == "default");
  render_checked(r, 4096, "shadow rays through a cloud");
  const vdb::DeviceGrid& g = r.media().grids.at(0);
  const glm::dmat4 w2i = glm::inverse(glm::dmat4(s.media[0].transform.matrix()) * g.index_to_world);
  const glm::dvec3 o(s.camera.position);
  vdb::Sampler sampler(g);
  std::vector<double> ref;
  double T_min = 1;
  for (auto d : camera_directions(s)) {
    const glm::dvec3 p = o + d * ((-1 - o.y) / d.y);  // on the floor
    const double tau = scale * integrate(
                                   [&](double y) {
                                     glm::dvec3 x(p.x, y, p.z);
                                     return double(sampler.trilinear(glm::dvec3(w2i * glm::dvec4(x, 1))));
                                   },
                                   -1, 4, 5000);
    T_min = std::min(T_min, std::exp(-tau));
    ref.push_back(albedo / M_PI * E * std::exp(-tau));
  }
  std::cout << "darkest floor point: T " << T_min << "\n";
  EXPECT_LT(T_min, 0.01);
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), ref), "floor lit through a cloud");
}

// Everything at once, where no closed form exists: a cloud with RGB albedo and emission inside bounded haze,
// over a floor, with an emissive panel, the sun, a point light and the environment, multiple scattering.
// volpath (pbrt-v4's algorithm) and the default estimator must converge to the same image, per pixel and
// channel, in both terms.
TEST(Estimator, VolpathAndDefaultAgreeOnAFullScene) {
  json j = json::parse(R"({
    "camera": {"position": [0.2, 0.6, 3.2], "target": [0, 0.2, 0], "fov_y": 45},
    "media": [{"procedural": {"kind": "cloud", "voxel_size": 0.08, "center": [0, 0.4, 0], "size": [1.6, 1.6, 1.6],
                              "density": 3, "seed": 4},
               "albedo": [0.9, 0.7, 0.5], "g": 0.4,
               "emission": {"mode": "scale", "grid": "density", "scale": 0.3}}],
    "haze": {"sigma_t": 0.15, "albedo": [0.8, 0.8, 0.9], "g": -0.2, "bounded": true,
             "bounds_min": [-2, -0.5, -2], "bounds_max": [2, 2, 2]},
    "surfaces": [{"mesh": {"kind": "box", "size": [4, 0.1, 4]}, "transform": {"translate": [0, -0.55, 0]},
                  "albedo": [0.6, 0.7, 0.5]},
                 {"mesh": {"kind": "plane", "size": [0.4, 0.4]}, "transform": {"translate": [0.9, 1.2, 0.3]},
                  "emission": [3, 3, 2]}],
    "lights": {"sun": {"direction": [0.4, 1, 0.3], "irradiance": 2, "angular_diameter": 2},
               "points": [{"position": [-0.8, 0.8, 0.6], "intensity": 1.5}],
               "environment": {"color": [0.2, 0.25, 0.35], "intensity": 1}},
    "render": {"width": 10, "height": 8, "pixel_jitter": false, "max_depth": 4, "volume_samples": 2}
  })");
  auto run = [&](const std::string& estimator, int spp) {
    json k = with_estimator(j, estimator);
    k["render"]["seed"] = estimator == "volpath" ? 2 : 1;  // independent estimates for the two-sample test
    scene::Scene s = make_scene(k);
    render::Renderer r(context(), s);
    render_checked(r, spp, estimator);
    return std::make_pair(estimate(r, glsl::ACC_VOL, glsl::ACC_VOL2, 3),
                          estimate(r, glsl::ACC_SURF, glsl::ACC_SURF2, 3));
  };
  auto [dv, ds] = run("default", 512);
  auto [vv, vs] = run("volpath", 1024);
  expect_unbiased(two_sample_test(vv, dv), "volume term, volpath against default");
  expect_unbiased(two_sample_test(vs, ds), "surface term, volpath against default");
}

// A dense sunlit cloud under a bright environment, 10x10, multiple scattering to depth 32: the walk's
// strategies (its sun lobe, split walks) against plain ones.
json sunlit_cloud_under_sky() {
  return {{"camera", {{"position", {0, 0.3, 3.4}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
          {"media", json::array({cloud_medium(8.0, 3, {0.95, 0.9, 0.8}, 0.5)})},
          {"lights",
           {{"sun", {{"direction", {0.5, 0.8, 0.3}}, {"irradiance", 1}}},
            {"environment", {{"color", {0.3, 0.35, 0.45}}, {"intensity", 4}}}}},
          {"render", {{"width", 10}, {"height", 10}, {"pixel_jitter", false}, {"max_depth", 32}}}};
}

// The default walk's sun lobe (render.sun_walk_probability, here 0.5) against phase sampling alone, in a
// dense sunlit cloud under a bright environment (the lobe's density enters the MIS weights of escaping walk
// rays and of NEE), per pixel and channel. The two sides have different seeds: with the same one their
// camera samples coincide and the test loses power. Injected: the lobe's directions without the weight
// f / pdf: pooled z +34..+50; NEE's MIS weight with the phase density alone (not the mixture's): chi2
// 213-224 against a critical 122, pooled z -4.1..-5.8.
TEST(Estimator, SunWalkLobeIsUnbiased) {
  json j = sunlit_cloud_under_sky();
  auto run = [&](double P, int spp, int seed = 1) {
    json k = j;
    k["render"]["seed"] = seed;
    k["render"]["sun_walk_probability"] = P;
    scene::Scene s = make_scene(k);
    render::Renderer r(context(), s);
    EXPECT_EQ(r.has_feature("SUN_WALK"), P > 0);  // P = 0: not a line of its code in the kernel
    render_checked(r, spp, P > 0 ? "sun lobe" : "phase sampling");
    return estimate(r, glsl::ACC_VOL, glsl::ACC_VOL2, 3);
  };
  expect_unbiased(two_sample_test(run(0.5, 2048, 7), run(0, 2048)), "sun lobe against phase sampling");
}

// The volume term of sunlit_cloud_under_sky with render.walk_splits K (0: learned; 1: not a line of the
// splits' code in the kernel).
Estimate split_cloud(int K, int spp, int seed) {
  json k = sunlit_cloud_under_sky();
  k["render"]["seed"] = seed;
  k["render"]["walk_splits"] = K;
  render::Renderer r(context(), make_scene(k));
  EXPECT_EQ(r.has_feature("WALK_SPLITS"), K != 1);
  EXPECT_EQ(r.has_feature("WALK_SPLITS_AUTO"), K == 0);
  render_checked(r, spp, K == 0 ? "learned splits" : K > 1 ? "split walks" : "one walk");
  // Learned K* is 3.1-3.4 over seeds 1-6. Injected: no dispatch of K 2 while K* < 1 during learning
  // (walk_splits_choose): seeds 1 and 4, or 2 and 5, of these six ended at K 1, one rare large sample having
  // taken K* below 1 early, after which no walk variance was measured again.
  if (K == 0) EXPECT_GE(r.walk_splits_stats().at("k").get<double>(), 1.5) << "a dense cloud pays for splits";
  return estimate(r, glsl::ACC_VOL, glsl::ACC_VOL2, 3);
}

// Walks split at the camera sample's first medium vertex (render.walk_splits 3, WALK_SPLITS) against one
// walk, per pixel and channel, on a dense sunlit cloud under an environment (escaping walks add their MIS
// share). Injected: the walks' throughput not divided by K (3x the multiple scattering): pooled z +61..+75;
// their first directions' strata without the random offset (the walks' directions fixed): +15..+17;
// the saved walks restarted at depth 2 instead of 1 (one event fewer allowed): not seen at max_depth 32,
// where the last event carries nothing measurable.
TEST(Estimator, WalkSplitsAreUnbiased) {
  expect_unbiased(two_sample_test(split_cloud(3, 1024, 5), split_cloud(1, 2048, 1)),
                  "three walks against one");
}

// Learned walk splits (render.walk_splits 0, WALK_SPLITS_AUTO): each dispatch's K comes from earlier
// dispatches only, so the image is one walk's, per pixel and channel. Injected: the walks' throughput not
// divided by K: pooled z +133..+141; their first directions' strata without the random offset: +24..+27.
TEST(Estimator, LearnedWalkSplitsAreUnbiased) {
  expect_unbiased(two_sample_test(split_cloud(0, 1024, 5), split_cloud(1, 2048, 1)),
                  "learned splits against one walk");
}

// The learner's split of the variance against fixed K: a grey sunlit cloud, so that a sample's channel sum is
// 3x its red channel. The relative variance per sample at K walks, measured from the pixel sums as the
// learner weighs it (1 / (m^2 + SPLIT_EPS2), m the pixel's mean), against V_b + V_w / K from the learned
// totals. Measured: K 1 predicted 0.511 against 0.487, K 4 0.176 against 0.175. Injected (before the walks'
// first directions were stratified): a third of the walks' variance (their per-channel variances summed
// instead of the variance of the channel sum): K 4 predicted 0.310 against 0.179.
TEST(Estimator, LearnedSplitVariancesPredictFixedSplits) {
  json j = {{"camera", {{"position", {0, 0.3, 3.4}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"media", json::array({cloud_medium(8.0, 3, {0.9, 0.9, 0.9}, 0.5)})},
            {"lights", {{"sun", {{"direction", {0.5, 0.8, 0.3}}, {"irradiance", 4}}}}},
            {"render", {{"width", 12}, {"height", 12}, {"pixel_jitter", false}, {"max_depth", 32}}}};
  auto measured = [&](int K) {
    json k = j;
    k["render"]["walk_splits"] = K;
    k["render"]["seed"] = 10 + K;
    render::Renderer r(context(), make_scene(k));
    render_checked(r, 2048, "fixed splits");
    const Estimate e = estimate(r, glsl::ACC_L, glsl::ACC_L2, 3);
    double sum = 0;
    for (size_t p = 0; p < e.pixels(); ++p) {
      const double m = 3 * e.mean[3 * p], var = 9 * e.var_of_mean[3 * p] * r.samples();
      sum += var / (m * m + glsl::SPLIT_EPS2);
    }
    return sum / double(e.pixels());
  };
  json k = j;
  k["render"]["walk_splits"] = 0;
  render::Renderer r(context(), make_scene(k));
  render_checked(r, 1024, "learned splits");
  const json st = r.walk_splits_stats();
  const double V_w = st.at("relative_variance_walk"), V_b = st.at("relative_variance_between");
  for (int K : {1, 4}) {
    const double predicted = V_b + V_w / K, m = measured(K);
    std::cout << "K " << K << ": predicted " << predicted << ", measured " << m << "\n";
    EXPECT_NEAR(predicted / m, 1.0, 0.1) << "K " << K;
  }
  EXPECT_GT(V_w, 2 * V_b) << "the walk carries most of a dense cloud's variance";
}

// Where the walks carry little, the learned K is 1: a shaft of sunlight through a 1 x 1 opening into thin
// haze, seen from the side, depth 2 (the efficiency bench's haze_shaft: V_b 0.024 against V_w 0.005 there,
// where a uniformly lit cube of haze has V_w 27x V_b and learns K 5). Without walks (max_depth 1) or with
// volpath nothing is learned and the kernel has none of its code.
TEST(Estimator, LearnedSplitsStayAtOneInThinHaze) {
  json j = bench::efficiency_case_scene("haze_shaft", 0.25);  // 32 x 18, max_depth 2
  j["render"]["walk_splits"] = 0;
  render::Renderer r(context(), make_scene(j));
  render_checked(r, 128, "learned splits in a thin shaft");
  const json st = r.walk_splits_stats();
  EXPECT_EQ(st.at("k").get<double>(), 1.0) << st.dump();
  // A cube of the same haze lit throughout: the second event carries the variance, and walks split (measured
  // K* 5.1). With the cost counted in lookups alone (no term per tracking query) the cube's camera part cost
  // nothing, and K* came out as 1.
  json cube = {{"camera", {{"position", {0, 0.2, 3.4}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
               {"haze", haze_cube(0.1, {0.9, 0.9, 0.9}, 0.0, 1.5)},
               {"lights", {{"sun", {{"direction", {0.4, 1, 0.3}}, {"irradiance", 3}}}}},
               {"render", {{"width", 12}, {"height", 12}, {"max_depth", 2}, {"walk_splits", 0}}}};
  render::Renderer rc(context(), make_scene(cube));
  render_checked(rc, 256, "learned splits in a lit cube of haze");
  const double k_cube = rc.walk_splits_stats().at("k").get<double>();
  EXPECT_GT(k_cube, 3.0) << rc.walk_splits_stats().dump();
  EXPECT_LT(k_cube, 8.0) << rc.walk_splits_stats().dump();
  for (const auto& [key, value] : {std::pair<const char*, json>{"max_depth", 1}, {"estimator", "volpath"}}) {
    json k = j;
    k["render"][key] = value;
    render::Renderer r1(context(), make_scene(k));
    EXPECT_FALSE(r1.has_feature("WALK_SPLITS")) << key;
    EXPECT_TRUE(r1.walk_splits_stats().empty()) << key;
  }
}

// Decomposition tracking with the haze in its control: one grey cloud without emission inside haze of another
// albedo and g, so that a collision attributed to the wrong medium changes the image; the default estimator
// (DECOMPOSITION) against volpath (plain delta tracking), per pixel and channel. Injected: the control's
// collisions given to the cloud where they belong to the haze and back: pooled z +32..+38; a collision above
// the control left to the lookup's choice of medium (which may pick the haze, all of whose collisions are
// the control's): pooled z -4.6 in red against a critical 4.31 (the haze's share there is small).
TEST(Estimator, DecompositionTrackingAgreesWithVolpathInHaze) {
  json j = {{"camera", {{"position", {0, 0.2, 3.4}}, {"target", {0, 0, 0}}, {"fov_y", 40}}},
            {"media", json::array({cloud_medium(4.0, 6, {0.95, 0.95, 0.95}, 0.6)})},
            {"haze", haze_cube(0.6, {0.3, 0.4, 0.5}, -0.3, 1.2)},
            {"lights", {{"sun", {{"direction", {0.4, 1, 0.3}}, {"irradiance", 3}}}}},
            {"render", {{"width", 10}, {"height", 10}, {"pixel_jitter", false}, {"max_depth", 4}}}};
  auto run = [&](const std::string& estimator, int spp, uint32_t seed) {
    json k = with_estimator(j, estimator);
    k["render"]["seed"] = seed;
    render::Renderer r(context(), make_scene(k));
    EXPECT_EQ(r.has_feature("DECOMPOSITION"), estimator == "default");
    render_checked(r, spp, estimator);
    return estimate(r, glsl::ACC_L, glsl::ACC_L2, 3);
  };
  expect_unbiased(two_sample_test(run("default", 1024, 1), run("volpath", 2048, 2)),
                  "default (decomposition tracking) against volpath");
}

// References in double: the device sums at most Renderer::kFoldSamples samples in float before they are
// folded into double sums on the host. The scheme at 2^24 samples of one value, simulated on the CPU with
// the same batch: a float running sum stops growing once a sample is below half its ulp (the mean comes out
// 9% low here), the folded one keeps the mean and the variance to float rounding.
TEST(ReferenceSums, FoldedSumsConvergeAt2To24Samples) {
  const int64_t n = int64_t(1) << 24;
  const float x = 0.3f, x2 = x * x;
  float plain = 0, batch = 0, batch2 = 0;
  double folded = 0, folded2 = 0;
  for (int64_t i = 1; i <= n; ++i) {
    plain += x;
    batch += x;
    batch2 += x2;
    if (i % render::Renderer::kFoldSamples == 0) {
      folded += batch;
      folded2 += batch2;
      batch = batch2 = 0;
    }
  }
  folded += batch;
  folded2 += batch2;
  const double mean = folded / double(n), var = folded2 / double(n) - mean * mean;
  std::cout << "mean of 2^24 samples of 0.3: float sum " << plain / double(n) << ", folded " << mean << "\n";
  EXPECT_LT(plain / double(n), 0.95 * x);  // the failure folding prevents: 0.274 measured
  EXPECT_NEAR(mean, x, 1e-6 * x);
  // A constant has no variance; the folded second moment minus the squared mean leaves float rounding of the
  // batches' squares: 9.9e-6 x^2 measured.
  EXPECT_NEAR(var, 0.0, 3e-5 * x2);
}

// The renderer folds: past kFoldSamples the sums are double on the host, the resolve reads them, and an
// estimate made of 2.5 folds has the mean and variance of the estimator. Injected: a fold that drops the
// device's sums: mean 0, z -50. volpath's transmittance through a
// homogeneous slab is a 0/1 sample with mean T and variance T (1 - T), both known.
TEST(ReferenceSums, RendererFoldsIntoDoubleSums) {
  json j = with_estimator(slab_camera(1), "volpath");
  j["haze"] = haze_slab(0.7, 0.5, 0);
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  const int n = 2 * render::Renderer::kFoldSamples + render::Renderer::kFoldSamples / 2;
  render::Image img = render_checked(r, n, "folded render");
  EXPECT_EQ(r.folded_samples(), n);  // two folds while sampling, the rest at the resolve
  const double T = std::exp(-0.7 / camera_directions(s)[0].y);
  Estimate e = estimate(r, ACC_T, ACC_T2);
  const double se = std::sqrt(T * (1 - T) / n);
  std::cout << "folded mean " << e.mean[0] << ", T " << T << ", z " << (e.mean[0] - T) / se << "\n";
  EXPECT_LT(std::abs(e.mean[0] - T), 3.89 * se);
  // The sample variance of the 0/1 samples is mean (1 - mean) exactly (n / (n - 1) aside).
  EXPECT_NEAR(e.var_of_mean[0] * n, e.mean[0] * (1 - e.mean[0]) * n / (n - 1), 1e-9);
  // The resolve read the folded sums: its transmittance layer is their mean.
  EXPECT_NEAR(img.data[glsl::OUT_T], e.mean[0], 1e-6);
}

// The statistic itself, on synthetic normal estimates with known means: it accepts unbiased ones and rejects
// a bias of half a standard error per pixel over 144 pixels (pooled z 6 against a critical 4.3).
TEST(BiasStatistic, AcceptsNoBiasAndRejectsAKnownOne) {
  std::mt19937 gen(5);
  std::normal_distribution<double> normal;
  int rejected_unbiased = 0, rejected_biased = 0;
  const int trials = 200;
  for (int t = 0; t < trials; ++t) {
    Estimate e;
    e.channels = 3;
    std::vector<double> ref;
    for (int p = 0; p < 144; ++p) ref.push_back(1.0 + 0.01 * p);
    for (int p = 0; p < 144; ++p)
      for (int c = 0; c < 3; ++c) {
        const double se = 0.05 * (1 + c);
        e.mean.push_back(ref[size_t(p)] + se * normal(gen));
        e.var_of_mean.push_back(se * se);
      }
    rejected_unbiased += !bias_test(e, ref).passed();
    Estimate b = e;
    for (size_t i = 0; i < b.mean.size(); ++i) b.mean[i] += 0.5 * std::sqrt(b.var_of_mean[i]);
    rejected_biased += !bias_test(b, ref).passed();
  }
  std::cout << "rejected: unbiased " << rejected_unbiased << ", biased " << rejected_biased << " of "
            << trials << "\n";
  EXPECT_LE(rejected_unbiased, 1);  // alpha = 1e-4 per test: expected 0.02 of 200
  EXPECT_GE(rejected_biased, 0.95 * trials);
}

}  // namespace
}  // namespace haze::test
