// Numerical stability at the extremes of every valid input (docs/rendering.md, numerical stability):
// densities from 1e-6 to 1e6, albedo 0 and 1, g at +-1, voxel sizes from 1e-4 to 1e4, emitters and lights up
// to 1e8, 1x1 images, cameras very far and very near. Every layer, both denoisers, the volume motion and the
// guide states must stay finite, and every render must end (ctest's timeout catches a hang). Guiding and both
// denoisers are on, and each case renders two frames so that the temporal passes run too.
#include <gtest/gtest.h>

#include <cmath>

#include "shaders/glsl.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using nlohmann::json;

json base_scene() {
  return json::parse(R"({
    "camera": {"position": [0, 0.5, 4], "target": [0, 0.3, 0], "fov_y": 50},
    "media": [{"procedural": {"kind": "cloud", "voxel_size": 0.1, "center": [0, 0.5, 0], "size": [1.6, 1.6, 1.6],
                              "density": 2, "seed": 2},
               "albedo": [0.8, 0.8, 0.8], "g": 0.3,
               "emission": {"mode": "scale", "grid": "density", "scale": 0.5}}],
    "haze": {"sigma_t": 0.2, "albedo": [0.9, 0.9, 0.9], "g": 0.2, "bounded": true,
             "bounds_min": [-3, -1, -3], "bounds_max": [3, 3, 3]},
    "surfaces": [{"mesh": {"kind": "box", "size": [6, 0.1, 6]}, "transform": {"translate": [0, -0.5, 0]},
                  "albedo": [0.7, 0.7, 0.7]},
                 {"mesh": {"kind": "plane", "size": [0.3, 0.3]}, "transform": {"translate": [1, 1.5, 0]},
                  "emission": [2, 2, 2]}],
    "lights": {"sun": {"direction": [0.3, 1, 0.2], "irradiance": 3},
               "points": [{"position": [-1, 1.2, 0.5], "intensity": 4}],
               "environment": {"color": [0.2, 0.3, 0.4], "intensity": 1}},
    "guiding": {"enabled": true, "spacing": 4},
    "render": {"width": 12, "height": 8, "max_depth": 3}
  })");
}

bool finite(const std::vector<float>& v) {
  for (float x : v)
    if (!std::isfinite(x)) return false;
  return true;
}

void expect_finite(render::Renderer& r, const std::string& what) {
  render::Image img;
  render::FrameCounters counters;
  for (int frame = 0; frame < 2; ++frame) {
    r.add_samples(2);
    img = r.resolve();
    counters += img.counters;
  }
  // Finite because nothing was dropped: no non-finite sample, no step-cap abort, no majorant violation.
  expect_no_discards(counters, what);
  EXPECT_TRUE(finite(img.data)) << what;
  for (size_t i = 0; i < img.gbuffer.size(); ++i) {
    if (i % glsl::G_STRIDE == glsl::G_INSTANCE) continue;  // an id stored as float bits (none: 0xffffffff)
    ASSERT_TRUE(std::isfinite(img.gbuffer[i]))
        << what << ": g-buffer channel " << i % glsl::G_STRIDE << " of pixel " << i / glsl::G_STRIDE << " is "
        << img.gbuffer[i];
  }
  for (const auto* d : {&img.surface_denoised, &img.volume_denoised})
    if (d->has_value()) {
      for (const auto& c : (*d)->colour) ASSERT_TRUE(std::isfinite(c.x + c.y + c.z)) << what;
      EXPECT_TRUE(finite((*d)->variance)) << what;
    }
  for (const auto& m : img.volume_motion) ASSERT_TRUE(std::isfinite(m.x + m.y + m.z + m.w)) << what;
  for (const auto& s : r.guide_states()) ASSERT_TRUE(std::isfinite(s.x + s.y + s.z + s.w)) << what;
  EXPECT_EQ(context().validation_messages(), 0u) << what;
}

struct ExtremeCase {
  const char* name;
  json patch;  // merged into the base scene (RFC 7386)
};
// What gtest prints for a case (ctest's names): its name, not its bytes.
void PrintTo(const ExtremeCase& c, std::ostream* os) {
  *os << c.name;
}

class Extremes : public ::testing::TestWithParam<ExtremeCase> {};

TEST_P(Extremes, StayFinite) {
  json j = base_scene();
  j.merge_patch(GetParam().patch);
  scene::Scene s = make_scene(j);
  // One renderer per image size: its pipelines are shared by the cases (set_scene keeps them). The context
  // exists first, so that it is destroyed after them.
  gpu::Context& ctx = context();
  static std::map<std::pair<int, int>, std::unique_ptr<render::Renderer>> renderers;
  auto& r = renderers[{s.render.width, s.render.height}];
  if (!r)
    r = std::make_unique<render::Renderer>(ctx, s);
  else
    r->set_scene(s, 0);
  expect_finite(*r, GetParam().name);
}

// A `media` list for a patch: the base scene's cloud, 16 voxels across, with these medium keys.
json cloud(const json& keys, double voxel_size = 0.1) {
  json m = {{"procedural",
             {{"kind", "cloud"},
              {"voxel_size", voxel_size},
              {"center", {0, 0.5, 0}},
              {"size", {16 * voxel_size, 16 * voxel_size, 16 * voxel_size}},
              {"density", 2},
              {"seed", 2}}}};
  m.update(keys);
  return json::array({m});
}

json media_albedo(double a) {
  return {{"media", cloud({{"albedo", {a, a, a}}})}, {"haze", {{"albedo", {a, a, a}}}}};
}

json voxel(double v) {
  return {{"media", cloud(json::object(), v)}};
}

json density(double d) {
  return {{"media", cloud({{"density_scale", d}})}, {"haze", {{"sigma_t", d}}}};
}

json emission(double scale) {
  return {{"media", cloud({{"emission", {{"mode", "scale"}, {"grid", "density"}, {"scale", scale}}}})}};
}

json g(double v) {
  return {{"media", cloud({{"g", v}})}, {"haze", {{"g", v}}}};
}

// The same patch with the volpath estimator (its tracking has no control variate and other roulettes).
json volpath(json patch) {
  patch["render"]["estimator"] = "volpath";
  return patch;
}

INSTANTIATE_TEST_SUITE_P(
    Sweep, Extremes,
    ::testing::Values(
        ExtremeCase{"base", json::object()}, ExtremeCase{"medium_emission_1e8", emission(1e8)},
        ExtremeCase{"density_1e-6", density(1e-6)}, ExtremeCase{"density_1e6", density(1e6)},
        ExtremeCase{"albedo_0", media_albedo(0)}, ExtremeCase{"albedo_1", media_albedo(1)},
        ExtremeCase{"g_-1", g(-1)}, ExtremeCase{"g_1", g(1)}, ExtremeCase{"voxel_1e-4", voxel(1e-4)},
        ExtremeCase{"voxel_1e4", voxel(1e4)},
        ExtremeCase{"emitters_1e8",
                    {{"lights",
                      {{"sun", {{"irradiance", 1e8}}},
                       {"points", {{{"position", {-1, 1.2, 0.5}}, {"intensity", 1e8}}}}}}}},
        ExtremeCase{"one_pixel", {{"render", {{"width", 1}, {"height", 1}}}}},
        ExtremeCase{"camera_far", {{"camera", {{"position", {0, 0.5, 1e6}}}}}},
        ExtremeCase{"camera_near", {{"camera", {{"position", {0, 0.5, 1e-6}}, {"target", {0, 0.5, -1}}}}}},
        ExtremeCase{"sun_walk_max",
                    {{"media", cloud({{"albedo", {1, 1, 1}}})},
                     {"render", {{"max_depth", 64}, {"sun_walk_probability", 0.9}, {"sun_walk_g", 0.95}}}}},
        ExtremeCase{"walk_splits_max",
                    {{"media", cloud({{"albedo", {1, 1, 1}}})},
                     {"render", {{"max_depth", 64}, {"walk_splits", 16}}}}},
        ExtremeCase{
            "walk_splits_learned",
            {{"media", cloud({{"albedo", {1, 1, 1}}})}, {"render", {{"max_depth", 64}, {"walk_splits", 0}}}}},
        ExtremeCase{"volpath", volpath(json::object())},
        ExtremeCase{"volpath_density_1e-6", volpath(density(1e-6))},
        ExtremeCase{"volpath_density_1e6", volpath(density(1e6))},
        ExtremeCase{"volpath_albedo_1", volpath(media_albedo(1))},
        ExtremeCase{"volpath_emitters_1e8",
                    volpath({{"lights",
                              {{"sun", {{"irradiance", 1e8}}},
                               {"points", {{{"position", {-1, 1.2, 0.5}}, {"intensity", 1e8}}}}}}})}),
    [](const ::testing::TestParamInfo<ExtremeCase>& i) {
      std::string n = i.param.name;
      for (char& c : n)
        if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
      return n;
    });

}  // namespace
}  // namespace haze::test
