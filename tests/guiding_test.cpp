// Distance guiding, virtual points and the volume denoiser in the renderer (lavapipe, real shaders, the
// validation layer on). A light shaft with a known position: the sun straight above shines through a slit
// z in [5.5, 6.5] between two boxes at y = 3, into haze; the camera at y = 1 looks along +z, so every camera
// ray crosses the shaft where it meets the plane z = 6 (within half a unit).
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <numeric>

#include "shaders/glsl.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using nlohmann::json;

// `model` the guide's; `choose`: each vertex chooses its P (histogram), else P everywhere.
json shaft_scene(bool guiding, double P = 0.5, const std::string& model = "gaussian", bool choose = false) {
  json box = {{"kind", "box"}, {"size", {40, 0.1, 10}}};
  json j = {{"camera", {{"position", {0, 1, 0}}, {"target", {0, 1, 1}}, {"fov_y", 30}}},
            {"haze",
             {{"sigma_t", 0.1},
              {"albedo", {0.9, 0.9, 0.9}},
              {"bounded", true},
              {"bounds_min", {-20, -1, 0}},
              {"bounds_max", {20, 3, 12}}}},
            {"surfaces",
             {{{"mesh", box}, {"transform", {{"translate", {0, 3.05, 0.5}}}}},
              {{"mesh", box}, {"transform", {{"translate", {0, 3.05, 11.5}}}}}}},
            {"lights", {{"sun", {{"direction", {0, 1, 0}}, {"irradiance", 5}, {"angular_diameter", 0}}}}},
            {"render", {{"width", 32}, {"height", 24}, {"max_depth", 1}, {"pixel_jitter", false}}}};
  if (guiding)
    j["guiding"] = {{"enabled", true},
                    {"probability", P},
                    {"spacing", 8},
                    {"model", model},
                    {"choose_probability", choose}};
  return j;
}

// W-weighted mean of the guide states' means at grid vertex (x, y).
double vertex_mean(const std::vector<glm::vec4>& st, glm::uvec2 grid, uint32_t K, uint32_t x, uint32_t y) {
  double w = 0, wm = 0;
  for (uint32_t k = 0; k < K; ++k) {
    glm::vec4 s = st[(size_t(y) * grid.x + x) * K + k];
    float g = glsl::guide_weight(s, 12.f);
    w += g;
    wm += g * glsl::guide_mean(s);
  }
  return w > 0 ? wm / w : -1;
}

// The guide starts empty and learns the shaft: after a few frames the states at the image's centre vertex
// put their weighted mean within 0.4 of the shaft's centre (t = 6 there).
TEST(Guiding, StatesLearnTheShaftPosition) {
  scene::Scene s = make_scene(shaft_scene(true));
  render::Renderer r(context(), s);
  ASSERT_TRUE(r.has_feature("GUIDING"));
  glm::uvec2 grid = guiding::grid_size(s.guiding, uint32_t(s.render.width), uint32_t(s.render.height));
  EXPECT_EQ(grid, glm::uvec2(32 / 8 + 2, 24 / 8 + 2));
  std::vector<double> error;
  for (int frame = 0; frame < 4; ++frame) {
    if (frame > 0) r.set_scene(s, uint32_t(frame), &s);
    r.add_samples(4);
    r.resolve();
    double mu = vertex_mean(r.guide_states(), grid, 10, 2, 1);  // pixel (16, 8): t = 6 / d.z
    error.push_back(std::abs(mu - 6.0));
    std::cout << "frame " << frame << ": centre vertex mean " << mu << "\n";
  }
  EXPECT_LT(error.back(), 0.4);
  EXPECT_EQ(context().validation_messages(), 0u);
}

struct GuideShaftRun {
  Estimate e;
  double guided_share = 0;
};
GuideShaftRun guide_shaft_run(bool guiding, const std::string& model = "gaussian", bool choose = false) {
  scene::Scene s = make_scene(shaft_scene(guiding, 0.5, model, choose));
  render::Renderer r(context(), s);
  r.add_samples(64);
  render::Image img = r.resolve();
  GuideShaftRun out{estimate(r, glsl::ACC_VOL, glsl::ACC_VOL2)};
  out.guided_share =
      double(img.counters.guided) / double(std::max<uint64_t>(img.counters.distance_samples, 1));
  return out;
}
// Guided against unguided on the shaft: the ratio of their summed variances of the mean, and the z-score of
// their summed difference.
struct GuideShaftComparison {
  double variance_ratio, z;
};
GuideShaftComparison compare_guide_shaft(const Estimate& u, const Estimate& g) {
  double var_u = 0, var_g = 0, diff = 0, var = 0;
  for (size_t p = 0; p < u.mean.size(); ++p) {
    var_u += u.var_of_mean[p];
    var_g += g.var_of_mean[p];
    diff += g.mean[p] - u.mean[p];
    var += u.var_of_mean[p] + g.var_of_mean[p];
  }
  return {var_g / var_u, diff / std::sqrt(var)};
}
// The guided estimator's variance on the shaft falls well below transmittance sampling's at equal samples,
// and both agree within their noise.
TEST(Guiding, ReducesVarianceOnTheShaft) {
  const GuideShaftComparison c = compare_guide_shaft(guide_shaft_run(false).e, guide_shaft_run(true).e);
  std::cout << "variance guided / unguided: " << c.variance_ratio << ", z = " << c.z << "\n";
  EXPECT_LT(c.variance_ratio, 0.5);
  EXPECT_LT(std::abs(c.z), 3.89);
}

// The histogram guide with P chosen per vertex: the vertices learn the shaft, choose to guide (most samples
// are guided), the variance falls (measured 0.19 of unguided, guided share 0.79; the Gaussian states at P
// 0.5: 0.175), and the estimate agrees with the unguided one.
TEST(Guiding, HistogramChoosesPAndReducesVarianceOnTheShaft) {
  const GuideShaftRun u = guide_shaft_run(false), g = guide_shaft_run(true, "histogram", true);
  const GuideShaftComparison c = compare_guide_shaft(u.e, g.e);
  std::cout << "histogram: variance guided / unguided " << c.variance_ratio << ", guided share "
            << g.guided_share << ", z = " << c.z << "\n";
  EXPECT_GT(g.guided_share, 0.5);
  EXPECT_LT(c.variance_ratio, 0.4);
  EXPECT_LT(std::abs(c.z), 3.89);
}

// The histogram at a vertex below the image's centre after one frame of 4 samples per pixel: its
// contribution's mean position and its fullest bin lie on the shaft (t = 6 / d.z there, half a unit either
// side); its range R is the farthest exit from the haze along its rays (they leave it at z = 12).
TEST(Guiding, HistogramLearnsTheShaftPosition) {
  scene::Scene s = make_scene(shaft_scene(true, 0.5, "histogram", true));
  render::Renderer r(context(), s);
  ASSERT_TRUE(r.has_feature("GUIDE_HIST"));
  r.add_samples(4);
  r.resolve();
  const glm::uvec2 grid = guiding::grid_size(s.guiding, uint32_t(s.render.width), uint32_t(s.render.height));
  const uint32_t B = uint32_t(s.guiding.bins), stride = guiding::Guide::hist_stride(B);
  const std::vector<glm::vec4> raw = r.guide_states();
  ASSERT_EQ(raw.size() * 4, size_t(grid.x) * grid.y * stride);
  const float* h = &raw[0].x + size_t(2 * grid.x + 2) * stride;  // vertex (2, 2): pixel (16, 16)
  const glm::dvec3 d = camera_directions(s)[16 * 32 + 16];
  const double R = h[2 * B + 3];
  uint32_t fullest = 0;
  for (uint32_t b = 1; b < B; ++b)
    if (h[b] > h[fullest]) fullest = b;
  const double t_mean = h[2 * B + 1], t_fullest = (fullest + 0.5) / B * R;
  std::cout << "vertex (2, 2): mean " << t_mean << ", fullest bin at " << t_fullest << " (shaft at "
            << 6.0 / d.z << "), n " << h[2 * B] << ", P " << h[2 * B + 2] << ", R " << R << "\n";
  EXPECT_NEAR(t_mean, 6.0 / d.z, 0.4);
  EXPECT_NEAR(t_fullest, 6.0 / d.z, 0.5 / d.z + R / B);
  EXPECT_GT(R, 12.0 / d.z);
  EXPECT_LT(R, 12.0 / d.z * 1.1);
  EXPECT_NEAR(h[B + B - 1], (1 + glsl::GUIDE_FLOOR) * std::accumulate(h, h + B, 0.0), 1e-5 * h[B + B - 1]);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// One sample per pixel (one dispatch) is enough for a histogram: its range R comes from the haze's bounds
// before the first sample, so that dispatch already bins (its fullest bin lies on the shaft), and each
// sample also learns into a neighbour vertex, so the vertex counts more samples than its own 8 x 8 pixels
// drew. Injections caught: no R from the bounds (guide_vertex_range returning 0: the first dispatch only
// measures R, its bins stay empty), learning at the nearest vertex only (n = 64).
TEST(Guiding, HistogramBinsFromTheFirstSampleAndLearnsFromNeighbours) {
  scene::Scene s = make_scene(shaft_scene(true, 0.5, "histogram", true));
  render::Renderer r(context(), s);
  r.add_samples(1);
  r.resolve();
  const glm::uvec2 grid = guiding::grid_size(s.guiding, uint32_t(s.render.width), uint32_t(s.render.height));
  const uint32_t B = uint32_t(s.guiding.bins), stride = guiding::Guide::hist_stride(B);
  const std::vector<glm::vec4> raw = r.guide_states();
  const float* h = &raw[0].x + size_t(2 * grid.x + 2) * stride;  // vertex (2, 2): pixel (16, 16)
  const glm::dvec3 d = camera_directions(s)[16 * 32 + 16];
  const double R = h[2 * B + 3], n = h[2 * B];
  uint32_t fullest = 0;
  for (uint32_t b = 1; b < B; ++b)
    if (h[b] > h[fullest]) fullest = b;
  std::cout << "after one sample: vertex (2, 2) n " << n << ", R " << R << ", fullest bin at "
            << (fullest + 0.5) / B * R << " (shaft at " << 6.0 / d.z << ")\n";
  EXPECT_GT(R, 12.0 / d.z);
  EXPECT_LT(R, 12.0 / d.z * 1.1);
  EXPECT_GT(std::accumulate(h, h + B, 0.0), 0.0);
  EXPECT_NEAR((fullest + 0.5) / B * R, 6.0 / d.z, 0.5 / d.z + R / B);
  // 64 of its own; the neighbours' expected share is 64 minus the own pixels' bilinear weight (about 28).
  EXPECT_GT(n, 64 + 14);
  EXPECT_LT(n, 64 + 42);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The virtual point depth is the contribution-weighted mean distance of the samples: with single scattering
// all contribution comes from the shaft, so it lies inside the ray's stretch of the shaft, and on average at
// its middle.
TEST(VirtualPoints, DepthLiesOnTheShaft) {
  scene::Scene s = make_scene(shaft_scene(false));
  render::Renderer r(context(), s);
  r.add_samples(32);
  render::Image img = r.resolve();
  std::vector<double> acc = r.accum();
  auto dirs = camera_directions(s);
  int checked = 0, fallbacks = 0;
  double offset = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      glm::dvec3 d = dirs[size_t(y) * img.width + x];
      if (1 + 6.5 / d.z * d.y > 2.9) continue;  // the ray meets the ceiling first
      float vp = img.at(x, y, glsl::OUT_VPDEPTH);
      if (acc[(size_t(y) * img.width + x) * glsl::ACC_STRIDE + glsl::ACC_VP_W] == 0) {
        // No sample found the shaft (unguided, 32 samples): the fallback is the mean depth t_s.
        EXPECT_EQ(vp, img.at(x, y, glsl::OUT_DEPTH));
        ++fallbacks;
        continue;
      }
      EXPECT_GE(vp, 5.5 / d.z - 1e-3) << x << " " << y;
      EXPECT_LE(vp, 6.5 / d.z + 1e-3) << x << " " << y;
      offset += vp - 6.0 / d.z;
      ++checked;
    }
  EXPECT_GT(checked, 300);
  EXPECT_LT(fallbacks, checked / 5);
  EXPECT_LT(std::abs(offset / checked), 0.05);
}

// The volume instance runs where the scene has media, on the volume signal with the volume motion; the
// denoised layer composites both instances; guiding and the volume instance allocate only when used.
TEST(VolumeDenoiser, RunsAndCompositesWithItsOwnLedgerCategories) {
  scene::Scene s = make_scene(shaft_scene(true));
  scene::Scene moved = s;
  moved.camera.position.x += 0.2f;
  moved.camera.target.x += 0.2f;
  render::Renderer r(context(), s);
  render::Image img;
  for (int f = 0; f < 3; ++f) {
    const scene::Scene& now = f % 2 ? moved : s;
    const scene::Scene& before = f % 2 ? s : moved;
    if (f > 0) r.set_scene(now, uint32_t(f), &before);
    r.add_samples(2);
    img = r.resolve();
  }
  ASSERT_TRUE(img.volume_denoised.has_value());
  ASSERT_TRUE(img.surface_denoised.has_value());
  ASSERT_EQ(img.volume_motion.size(), size_t(img.width) * img.height);
  // The shaft's points moved sideways: most pixels got a virtual point, with horizontal motion.
  int landed = 0;
  for (const glm::vec4& m : img.volume_motion) {
    ASSERT_TRUE(std::isfinite(m.x) && std::isfinite(m.y) && std::isfinite(m.z));
    if (m.w > 0.5f) ++landed;
  }
  EXPECT_GT(landed, img.width * img.height / 2);
  double sum = 0;
  for (const auto& c : img.volume_denoised->colour) sum += c.x + c.y + c.z;
  EXPECT_GT(sum, 0);
  nlohmann::json st = r.stats();
  const std::string ledger = st["memory"].dump();
  for (const char* cat : {"svgf.volume per-frame temporaries", "svgf.volume previous-frame data",
                          "svgf.surface per-frame temporaries", "guiding state", "volume motion"})
    EXPECT_NE(ledger.find(cat), std::string::npos) << cat;
  EXPECT_TRUE(st["passes"].contains("svgf.volume.accumulate"));
  EXPECT_TRUE(st["passes"].contains("guide_reproject"));

  // Guiding off, no media: none of it.
  json plain = shaft_scene(false);
  plain.erase("haze");
  scene::Scene p = make_scene(plain);
  render::Renderer q(context(), p);
  q.add_samples(1);
  render::Image qi = q.resolve();
  EXPECT_FALSE(qi.volume_denoised.has_value());
  EXPECT_TRUE(qi.volume_motion.empty());
  EXPECT_FALSE(q.has_feature("GUIDING"));
  EXPECT_TRUE(q.guide_states().empty());
  EXPECT_EQ(context().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze::test
