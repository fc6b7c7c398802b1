// Chromatic media (media[].sigma_t_color, haze.sigma_t_color) on the GPU against closed forms and 1D
// integrals per channel, both estimators. Significance fixed before looking: alpha = 1e-4 per test
// (test_util.hpp bias_test: per pixel and per channel, the chi-square of the z-scores and each channel's
// pooled z, with the estimator's own per-pixel variance), fixed seeds. Nothing may be discarded.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "expect_error.hpp"
#include "shaders/glsl.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using glsl::ACC_L;
using glsl::ACC_L2;
using glsl::ACC_SURF;
using glsl::ACC_SURF2;
using nlohmann::json;

const glm::dvec3 kBlueTint{0.3, 0.6, 1.0};

// Camera one unit below a slab y in [0, 1], looking up.
json slab_scene(const std::string& estimator, double fov = 40, int size = 12) {
  return {{"camera", {{"position", {0, -1, 0}}, {"target", {0, 1, 0}}, {"up", {0, 0, 1}}, {"fov_y", fov}}},
          {"render",
           {{"width", size},
            {"height", size},
            {"pixel_jitter", false},
            {"max_depth", 1},
            {"estimator", estimator}}}};
}

json tinted_haze(double sigma, double albedo, glm::dvec3 c, double g = 0) {
  return {
      {"sigma_t", sigma}, {"sigma_t_color", {c.x, c.y, c.z}}, {"albedo", {albedo, albedo, albedo}}, {"g", g},
      {"bounded", true},  {"bounds_min", {-100, 0, -100}},    {"bounds_max", {100, 1, 100}}};
}

// A constant VDB box taller than the slab clipped to it by its bounds: exactly the homogeneous slab, tracked.
json tinted_box(double sigma, double albedo, glm::dvec3 c, double g = 0) {
  return {{"procedural",
           {{"kind", "box"},
            {"voxel_size", 0.05},
            {"center", {0, 0.5, 0}},
            {"size", {8, 1.4, 8}},
            {"density", 1.0}}},
          {"density_scale", sigma},
          {"sigma_t_color", {c.x, c.y, c.z}},
          {"albedo", {albedo, albedo, albedo}},
          {"g", g},
          {"bounds_min", {-100, 0, -100}},
          {"bounds_max", {100, 1, 100}}};
}

void put_medium(json& j, bool vdb, const json& haze, const json& box) {
  if (vdb)
    j["media"] = json::array({box});
  else
    j["haze"] = haze;
}

// Pooled z of one channel, each pixel's variance floored at float rounding (closed forms have none).
double pooled_z(const Estimate& e, const std::vector<double>& ref, int k) {
  double diff = 0, var = 0;
  for (size_t p = 0; p < ref.size(); ++p) {
    diff += e.mean[p * 3 + k] - ref[p];
    var += e.var_of_mean[p * 3 + k] + std::pow(kFloatPrecision * ref[p], 2);
  }
  return diff / std::sqrt(var);
}

struct ChromaticCase {
  std::string estimator;
  bool vdb;
  std::string name() const { return estimator + (vdb ? " vdb" : " haze"); }
};
// What gtest prints for a case (ctest's names): its name, not its bytes.
void PrintTo(const ChromaticCase& c, std::ostream* os) {
  *os << c.name();
}
class ChromaticP : public ::testing::TestWithParam<ChromaticCase> {};
INSTANTIATE_TEST_SUITE_P(Estimators, ChromaticP,
                         ::testing::Values(ChromaticCase{"default", false}, ChromaticCase{"default", true},
                                           ChromaticCase{"volpath", false}, ChromaticCase{"volpath", true}),
                         [](const auto& i) { return i.param.estimator + (i.param.vdb ? "_vdb" : "_haze"); });

// Beer-Lambert per channel: a white environment seen through an absorbing slab (albedo 0) is
// exp(-sigma c_k / cos) in channel k. The default estimator takes the haze in closed form (exact) and the
// VDB box's T from its delta-tracked camera sample; volpath delta-tracks both (spectral tracking's weights).
// Injected: the haze's closed form with the grey exp(-tau) (haze_transmittance without the colour): default
// haze, 176 exact mismatches, pooled z -2.6e5 and -1.2e5 in channels 0 and 1; a null collision's spectral
// tracking weight without its 1 / (1 - P_r): pooled z -113 and -52 in channels 0 and 1 (volpath; the default
// with the VDB box, whose transmittance comes from the delta-tracked camera sample, -114 and -52).
TEST_P(ChromaticP, BeerLambertPerChannel) {
  const ChromaticCase c = GetParam();
  const double sigma = 1.2;
  json j = slab_scene(c.estimator);
  put_medium(j, c.vdb, tinted_haze(sigma, 0, kBlueTint), tinted_box(sigma, 0, kBlueTint));
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  EXPECT_TRUE(r.has_feature("CHROMATIC"));
  render_checked(r, 256, "Beer-Lambert " + c.name());
  std::vector<double> ref;
  for (auto d : camera_directions(s))
    for (int k = 0; k < 3; ++k) ref.push_back(std::exp(-sigma * kBlueTint[k] / d.y));
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), ref), "Beer-Lambert, " + c.name());
}

// Single scattering of a vertical sun in the slab, per channel: the 1D integral along each camera ray of
// sigma_s,k p E T_camera,k T_sun,k with sigma_t,k = sigma c_k.
// Injected: the camera sample's weight T sigma_t / q with the grey sigma_t (the chosen component's colour
// dropped): default haze, pooled z +789 and +456 in channels 0 and 1; a real collision's spectral tracking
// weight without its 1 / P_r: volpath pooled z -97, -83, -58, default VDB box (delta-tracked camera samples)
// -175, -150, -101.
TEST_P(ChromaticP, SunlitSlabSingleScatteringPerChannel) {
  const ChromaticCase c = GetParam();
  const double sigma = 0.8, albedo = 0.7, g = 0.4, E = 2.0;
  json j = slab_scene(c.estimator);
  put_medium(j, c.vdb, tinted_haze(sigma, albedo, kBlueTint, g), tinted_box(sigma, albedo, kBlueTint, g));
  j["lights"] = {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", E}, {"angular_diameter", 0}}}};
  j["render"]["volume_samples"] = 2;
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 256, "sunlit slab " + c.name());
  std::vector<double> ref;
  for (auto d : camera_directions(s)) {
    const double p = glsl::hg_phase(float(d.y), float(g));
    for (int k = 0; k < 3; ++k) {
      const double sk = sigma * kBlueTint[k];
      // sigma_s T_cam T_sun along the ray inside y in [0, 1]: T_cam = exp(-sk y / d.y), T_sun = exp(-sk (1 -
      // y)).
      ref.push_back(integrate(
          [&](double y) { return sk * albedo * p * E * std::exp(-sk * y / d.y - sk * (1 - y)) / d.y; }, 0, 1,
          2000));
    }
  }
  expect_unbiased(bias_test(estimate(r, ACC_L, ACC_L2, 3), ref), "sunlit slab, " + c.name());
}

// A blue-tinted extinction with white albedo turns a white sun orange through a thick slab: the sun's disk
// seen straight through it (the surface term: T_k times the disk's radiance, rendered without the slab) is
// exp(-sigma c_k) of it per channel, red > green > blue.
TEST_P(ChromaticP, WhiteSunTurnsOrangeThroughThickSlab) {
  const ChromaticCase c = GetParam();
  const double sigma = 3.0;
  json j = slab_scene(c.estimator, 4.0, 8);
  j["lights"] = {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", 2.0}, {"angular_diameter", 20}}}};
  std::vector<double> disk;
  {
    scene::Scene s = make_scene(j);
    render::Renderer r(context(), s);
    render_checked(r, 1, "bare sun");
    Estimate e = estimate(r, ACC_SURF, ACC_SURF2, 3);
    disk = e.mean;
    ASSERT_GT(disk[0], 0.0);
  }
  put_medium(j, c.vdb, tinted_haze(sigma, 1.0, kBlueTint), tinted_box(sigma, 1.0, kBlueTint));
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 512, "orange sun " + c.name());
  Estimate e = estimate(r, ACC_SURF, ACC_SURF2, 3);
  auto dirs = camera_directions(s);
  std::vector<double> ref;
  for (size_t p = 0; p < dirs.size(); ++p)
    for (int k = 0; k < 3; ++k) ref.push_back(disk[p * 3 + k] * std::exp(-sigma * kBlueTint[k] / dirs[p].y));
  expect_unbiased(bias_test(e, ref), "orange sun, " + c.name());
  double rgb[3] = {0, 0, 0};
  for (size_t p = 0; p < dirs.size(); ++p)
    for (int k = 0; k < 3; ++k) rgb[k] += e.mean[p * 3 + k];
  std::cout << "sun through the slab (mean rgb): " << rgb[0] / dirs.size() << " " << rgb[1] / dirs.size()
            << " " << rgb[2] / dirs.size() << "\n";
  EXPECT_GT(rgb[0], 2.0 * rgb[1]);
  EXPECT_GT(rgb[1], 2.0 * rgb[2]);
}

// Extremes: a channel with no extinction and one 1000 times the others. No sample is discarded (non-finite,
// step cap); the clear and the middle channel's transmittance (the surface term under a white environment)
// are unbiased (pooled z within the test's 3.89; ratio tracking keeps the clear channel at 1 exactly,
// spectral tracking's null weights only in expectation), the opaque one is 0.
TEST_P(ChromaticP, ZeroAndHugeChannelsStayFinite) {
  const ChromaticCase c = GetParam();
  const glm::dvec3 tint{0.0, 1.0, 1000.0};
  json j = slab_scene(c.estimator, 40, 6);
  j["render"]["max_depth"] = 4;
  put_medium(j, c.vdb, tinted_haze(0.5, 0.8, tint), tinted_box(0.5, 0.8, tint));
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  render_checked(r, 64, "extreme tint " + c.name());
  Estimate e = estimate(r, ACC_SURF, ACC_SURF2, 3);
  auto dirs = camera_directions(s);
  std::vector<double> clear(dirs.size(), 1.0), middle;
  for (auto d : dirs) middle.push_back(std::exp(-0.5 / d.y));
  for (size_t p = 0; p < e.pixels(); ++p) {
    for (int k = 0; k < 3; ++k) EXPECT_TRUE(std::isfinite(e.mean[p * 3 + k]));
    EXPECT_LT(std::abs(e.mean[p * 3 + 2]), 1e-6) << "pixel " << p;  // optical depth 500 and more
  }
  const double z0 = pooled_z(e, clear, 0), z1 = pooled_z(e, middle, 1);
  std::cout << "extreme tint, " << c.name() << ": pooled z " << z0 << " (clear), " << z1 << " (middle)\n";
  EXPECT_LT(std::abs(z0), 3.89);
  EXPECT_LT(std::abs(z1), 3.89);
}

// A grey scene keeps the grey kernel: no CHROMATIC permutation.
TEST(Chromatic, GreyScenesKeepTheGreyPermutation) {
  json j = slab_scene("default");
  j["haze"] = tinted_haze(1.0, 0.5, {1, 1, 1});
  j["media"] = json::array({tinted_box(1.0, 0.5, {1, 1, 1})});
  j["lights"] = {{"environment", {{"color", {1, 1, 1}}}}};
  {
    render::Renderer r(context(), make_scene(j));
    EXPECT_FALSE(r.has_feature("CHROMATIC"));
    EXPECT_TRUE(r.has_feature("HETERO"));
  }
  j["media"][0]["sigma_t_color"] = {1, 1, 0.5};
  render::Renderer r(context(), make_scene(j));
  EXPECT_TRUE(r.has_feature("CHROMATIC"));
}

// sigma_t_color is checked: negative, non-finite and all-zero multipliers are refused by key.
TEST(Chromatic, BadMultipliersAreRefused) {
  json j = slab_scene("default");
  j["haze"] = tinted_haze(1.0, 0.5, {0, 0, 0});
  expect_error([&] { make_scene(j); }, {"haze.sigma_t_color", "[0, 0, 0]"});
  j["haze"]["sigma_t"] = 0;  // no medium: nothing to say
  make_scene(j);
  j.erase("haze");
  j["media"] = json::array({tinted_box(1.0, 0.5, {1, -1, 1})});
  expect_error([&] { make_scene(j); }, {"media[0].sigma_t_color"});
  j["media"] = json::array({tinted_box(1.0, 0.5, {0, 0, 0})});
  expect_error([&] { make_scene(j); }, {"media[0].sigma_t_color", "density_scale"});
}

}  // namespace
}  // namespace haze::test
