// The lights part: environment maps (reading, the importance sampler and its densities, background, NEE)
// and the choice of a light by power. GPU results come from the shaders' own functions
// (lights/light_probe.comp and the renderer) and are compared with independent CPU code: the map's density
// written out here, the shader's alias rule simulated over every random number, closed forms and numerical
// integrals. Significance is fixed before looking: alpha = 1e-4 per test (|z| < 3.89; chi-square critical
// values by Wilson-Hilferty at z = 3.719), fixed seeds.
#include "lights/lights.hpp"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfOutputFile.h>
#include <ImfRgbaFile.h>
#include <gtest/gtest.h>
#include <stb/stb_image_write.h>

#include <cmath>
#include <filesystem>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtx/component_wise.hpp>
#include <iostream>
#include <random>

#include "expect_error.hpp"
#include "gpu/kernel.hpp"
#include "lights/environment.hpp"
#include "shaders/glsl.hpp"
#include "temp_dir.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using nlohmann::json;

double chi2_critical(int df) {
  double a = 2.0 / (9.0 * df);
  double t = 1 - a + 3.719 * std::sqrt(a);
  return df * t * t * t;
}

// Chi-square of observed against expected counts, cells pooled in order until each expects at least 5.
double chi2(const std::vector<double>& observed, const std::vector<double>& expected, int* df) {
  double c = 0, po = 0, pe = 0;
  *df = -1;
  for (size_t i = 0; i < observed.size(); ++i) {
    po += observed[i];
    pe += expected[i];
    if (pe >= 5 || i + 1 == observed.size()) {
      c += (po - pe) * (po - pe) / std::max(pe, 1e-12);
      ++*df;
      po = pe = 0;
    }
  }
  return c;
}

// The documented orientation (lights/environment.hpp), written out independently of the shader: the
// local direction of map coordinates (u, v), and the map coordinates of a world direction under a turn of
// `rotate` degrees about +y.
glm::dvec3 map_direction(double u, double v) {
  const double theta = M_PI * v, phi = 2 * M_PI * u;
  return {-std::sin(phi) * std::sin(theta), std::cos(theta), std::cos(phi) * std::sin(theta)};
}
glm::dvec2 map_uv(glm::dvec3 world, double rotate) {
  const glm::dmat3 turn_back =
      glm::dmat3(glm::rotate(glm::dmat4(1), glm::radians(-rotate), glm::dvec3(0, 1, 0)));
  const glm::dvec3 l = glm::normalize(turn_back * world);
  double phi = std::atan2(-l.x, l.z);
  if (phi < 0) phi += 2 * M_PI;
  return {phi / (2 * M_PI), std::acos(std::clamp(l.y, -1.0, 1.0)) / M_PI};
}
glm::dvec3 world_direction(double u, double v, double rotate) {
  return glm::dmat3(glm::rotate(glm::dmat4(1), glm::radians(rotate), glm::dvec3(0, 1, 0))) *
         map_direction(u, v);
}

// A test map: the generated sky with a large sun, times a random factor per texel (so that a pixel off by
// one is seen), with one black row and a few black texels.
lights::EnvironmentMap test_map(uint32_t w, uint32_t h, uint32_t seed = 5) {
  lights::SkyParams p;
  p.width = w;
  p.height = h;
  p.sun_size = 16;
  p.sun_radiance = 40;
  p.sun_elevation = 40;
  lights::EnvironmentMap m = lights::make_sky(p);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> f(0.5f, 1.5f);
  for (auto& t : m.texels) t *= glm::vec3{f(rng), f(rng), f(rng)};
  for (uint32_t i = 0; i < w; ++i) m.texels[size_t(h - 2) * w + i] = glm::vec3(0);
  for (uint32_t k = 0; k < 5; ++k) m.texels[(size_t(k) * 7919) % (size_t(w) * h)] = glm::vec3(0);
  return m;
}

// P(pixel) of the sampler as documented: luminance times sin(theta) at the row's centre, normalised.
std::vector<double> map_probabilities(const lights::EnvironmentMap& m) {
  std::vector<double> p(m.texels.size());
  double sum = 0;
  for (uint32_t j = 0; j < m.height; ++j)
    for (uint32_t i = 0; i < m.width; ++i) {
      const glm::dvec3 L(m.texels[size_t(j) * m.width + i]);
      sum += p[size_t(j) * m.width + i] =
          (0.2126 * L.r + 0.7152 * L.g + 0.0722 * L.b) * std::sin(M_PI * (j + 0.5) / m.height);
    }
  for (double& x : p) x /= sum;
  return p;
}

// Runs lights/light_probe.comp: three vec4 per item (see the shader).
std::vector<glm::vec4> probe(const lights::Lights& L, const std::vector<glm::vec4>& points, uint32_t count,
                             uint32_t seed, uint32_t mode) {
  gpu::Context& ctx = context();
  glsl::GpuScene g{};
  L.fill(g);
  gpu::Buffer scene(ctx, "test scene", "test", sizeof(g), "GpuScene");
  scene.upload(&g, sizeof(g));
  gpu::Buffer pts(ctx, "test probe points", "test", points.size() * 16, "vec4");
  pts.upload(points);
  gpu::Buffer out(ctx, "test probe samples", "test", uint64_t(count) * 48, "vec4");
  gpu::KernelDecl d("lights/light_probe.comp");
  d.buffer("scene", sizeof(g)).buffer("points", points.size() * 16).buffer("samples", uint64_t(count) * 48);
  L.declare(d);
  gpu::Kernel k(ctx, std::move(d.push(16)));
  gpu::Bindings b;
  b.set("scene", scene).set("points", pts).set("samples", out);
  L.bind(b);
  const uint32_t push[4] = {count, uint32_t(points.size()), seed, mode};
  ctx.submit_and_wait([&](VkCommandBuffer cmd) { k.dispatch_1d(cmd, b, push, count); });
  return out.download_vector<glm::vec4>();
}

scene::Lights env_lights(const std::string& file, float rotate, float intensity = 1.f) {
  scene::Lights l;
  l.environment = scene::Environment{};
  l.environment->file = file;
  l.environment->rotate = rotate;
  l.environment->intensity = intensity;
  return l;
}

// Per pixel and channel z = (mean - ref) / sd of the mean: the chi-square of their squares over the pixels
// and the pooled z of the channel.
struct ZTest {
  double chi2 = 0, pooled = 0;
  int df = 0;
};
ZTest z_test(const std::vector<double>& diff, const std::vector<double>& var) {
  ZTest t;
  double sd = 0, sv = 0;
  for (size_t p = 0; p < diff.size(); ++p) {
    if (!(var[p] > 0)) continue;
    t.chi2 += diff[p] * diff[p] / var[p];
    ++t.df;
    sd += diff[p];
    sv += var[p];
  }
  t.pooled = sv > 0 ? sd / std::sqrt(sv) : 0;
  return t;
}
void expect_z(const ZTest& t, const std::string& what) {
  std::cout << "  " << what << ": chi2 " << t.chi2 << " (df " << t.df << ", critical " << chi2_critical(t.df)
            << "), pooled z " << t.pooled << "\n";
  EXPECT_GT(t.df, 0) << what;
  EXPECT_LT(t.chi2, chi2_critical(t.df)) << what;
  EXPECT_LT(std::abs(t.pooled), kZ) << what;
}
// A rendered channel (sum at `sum`, squares at `sq`) against a per-pixel reference.
ZTest z_test(const render::Renderer& r, uint32_t sum, uint32_t sq, const std::vector<double>& ref) {
  Estimate e = estimate(r, sum, sq);
  std::vector<double> diff(ref.size());
  for (size_t p = 0; p < ref.size(); ++p) diff[p] = e.mean[p] - ref[p];
  return z_test(diff, e.var_of_mean);
}

// ---------------------------------------------------------------------------------------------------------
// Reading maps.

TEST(EnvironmentMap, ReadsExrHdrAndPngAndCountsBadTexels) {
  TempDir dir("haze_lights");
  lights::EnvironmentMap m = test_map(8, 4);
  m.texels[1] = glm::vec3(1e-3f, 2e4f, 0.5f);
  const std::string exr = (dir.path() / "sky.exr").string(), hdr = (dir.path() / "sky.hdr").string();
  lights::write_environment_map(exr, m);
  lights::write_environment_map(hdr, m);
  lights::EnvironmentMap a = lights::read_environment_map(exr), b = lights::read_environment_map(hdr);
  ASSERT_EQ(a.width, 8u);
  ASSERT_EQ(a.height, 4u);
  ASSERT_EQ(b.width, 8u);
  for (size_t i = 0; i < m.texels.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(a.texels[i][c], m.texels[i][c]);
      // RGBE: 8 bits of mantissa under the texel's largest channel's exponent.
      const float top = std::max({m.texels[i].r, m.texels[i].g, m.texels[i].b});
      EXPECT_NEAR(b.texels[i][c], m.texels[i][c], top / 128);
    }
  EXPECT_EQ(a.replaced(), 0u);

  // PNG: 8-bit sRGB, decoded to linear.
  const std::string png = (dir.path() / "sky.png").string();
  const unsigned char px[6] = {0, 128, 255, 10, 20, 30};
  ASSERT_TRUE(stbi_write_png(png.c_str(), 2, 1, 3, px, 6));
  lights::EnvironmentMap p = lights::read_environment_map(png);
  ASSERT_EQ(p.width, 2u);
  EXPECT_NEAR(p.texels[0].g, 0.2158605, 1e-5);  // sRGB 128/255
  EXPECT_FLOAT_EQ(p.texels[0].b, 1.0f);

  // NaN, infinite and negative channels become 0 and are counted by kind.
  m.texels[0] = glm::vec3(NAN, -1.f, 2.f);
  m.texels[3] = glm::vec3(INFINITY, 1.f, -INFINITY);
  lights::write_environment_map(exr, m);
  lights::EnvironmentMap c = lights::read_environment_map(exr);
  EXPECT_EQ(c.nan, 1u);
  EXPECT_EQ(c.inf, 2u);
  EXPECT_EQ(c.negative, 1u);
  EXPECT_EQ(c.texels[0], glm::vec3(0, 0, 2));
  EXPECT_EQ(c.texels[3], glm::vec3(0, 1, 0));
}

// Grey (Y) and luminance-chroma (Y, RY, BY) OpenEXR maps are read as RGB: Y as grey at full float precision,
// YC through OpenEXR's conversion (half, chroma subsampled: a constant colour comes back within half's
// precision). Injected defect caught (measured): YC files read by the grey path (largest error 0.44, in B).
TEST(EnvironmentMap, ReadsGreyAndLuminanceChromaExr) {
  TempDir dir("haze_lights");
  const std::string grey = (dir.path() / "grey.exr").string(), yc = (dir.path() / "yc.exr").string();
  {
    Imf::Header h(4, 2);
    h.channels().insert("Y", Imf::Channel(Imf::FLOAT));
    std::vector<float> v = {0.5f, 1e6f, 0, 2, 3, 4, 5, 6};
    Imf::FrameBuffer fb;
    fb.insert("Y", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(v.data()), 4, 16));
    Imf::OutputFile f(grey.c_str(), h);
    f.setFrameBuffer(fb);
    f.writePixels(2);
  }
  const lights::EnvironmentMap g = lights::read_environment_map(grey);
  ASSERT_EQ(g.texels.size(), 8u);
  EXPECT_EQ(g.texels[1], glm::vec3(1e6f));  // beyond half's range
  EXPECT_EQ(g.texels[7], glm::vec3(6));
  {
    std::vector<Imf::Rgba> px(8 * 4, Imf::Rgba(0.2f, 0.5f, 0.9f, 1.f));
    Imf::RgbaOutputFile f(yc.c_str(), 8, 4, Imf::WRITE_YC);
    f.setFrameBuffer(px.data(), 1, 8);
    f.writePixels(4);
  }
  const lights::EnvironmentMap c = lights::read_environment_map(yc);
  ASSERT_EQ(c.texels.size(), 32u);
  glm::vec3 worst(0);
  for (const glm::vec3& t : c.texels) worst = glm::max(worst, glm::abs(t - glm::vec3(0.2f, 0.5f, 0.9f)));
  std::cout << "  YC round trip, largest error " << worst.r << " " << worst.g << " " << worst.b << "\n";
  EXPECT_LT(glm::compMax(worst), 0.01f);  // measured 0.004 (R)
}

// Runs f, expects a lights::Error whose one-line message has every piece.
void expect_lights_error(const std::function<void()>& f, std::initializer_list<std::string> pieces) {
  try {
    f();
    ADD_FAILURE() << "no error";
  } catch (const lights::Error& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    for (const auto& p : pieces) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
  }
}

TEST(EnvironmentMap, BadFilesAreOneLineErrorsNamingKeyAndFile) {
  TempDir dir("haze_lights");
  const std::string key = "lights.environment.file";
  const std::string missing = (dir.path() / "nope.exr").string();
  expect_lights_error([&] { lights::read_environment_map(missing); }, {key, missing, "no such file"});
  expect_lights_error([&] { lights::read_environment_map(dir.path().string()); },
                      {key, "not a regular file"});
  const std::string junk = dir.write("junk.hdr", "this is not an image").string();
  expect_lights_error([&] { lights::read_environment_map(junk); }, {key, junk, "cannot decode"});
  // A truncated EXR.
  lights::write_environment_map((dir.path() / "t.exr").string(), test_map(16, 8));
  std::filesystem::resize_file(dir.path() / "t.exr", 300);
  expect_lights_error([&] { lights::read_environment_map((dir.path() / "t.exr").string()); },
                      {key, "t.exr", "cannot read the OpenEXR file"});
  // An EXR without colour channels.
  const std::string z = (dir.path() / "depth.exr").string();
  {
    Imf::Header h(2, 2);
    h.channels().insert("Z", Imf::Channel(Imf::FLOAT));
    std::vector<float> v(4, 1.f);
    Imf::FrameBuffer fb;
    fb.insert("Z", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(v.data()), 4, 8));
    Imf::OutputFile f(z.c_str(), h);
    f.setFrameBuffer(fb);
    f.writePixels(2);
  }
  expect_lights_error([&] { lights::read_environment_map(z); }, {key, z, "needs channels R, G, B", "has Z"});
}

TEST(EnvironmentMap, SceneKeys) {
  TempDir dir("haze_lights");
  lights::write_environment_map((dir.path() / "sky.exr").string(), test_map(8, 4));
  const json base = {{"lights", {{"environment", {{"file", "sky.exr"}, {"rotate", 30}, {"intensity", 2}}}}}};
  const auto scene_file = dir.write("s.json", base.dump());
  scene::Scene s = scene::load(scene_file.string());
  ASSERT_TRUE(s.lights.environment);
  EXPECT_EQ(s.lights.environment->file, (dir.path() / "sky.exr").string());  // relative to the scene file
  EXPECT_EQ(s.lights.environment->rotate, 30.f);
  EXPECT_EQ(s.lights.choice, "power");
  // A map and a colour are refused together; a missing file, a bad choice and a turn out of range name the
  // key.
  json both = base;
  both["lights"]["environment"]["color"] = {1, 1, 1};
  expect_error([&] { scene::load(dir.write("b.json", both.dump()).string()); },
               {"lights.environment.color", "remove color"});
  json missing = base;
  missing["lights"]["environment"]["file"] = "gone.hdr";
  expect_error([&] { scene::load(dir.write("m.json", missing.dump()).string()); },
               {"lights.environment.file", "gone.hdr", "no such file"});
  expect_error([&] { scene::load(scene_file.string(), {"lights.choice=random"}); },
               {"lights.choice", "power"});
  expect_error([&] { scene::load(scene_file.string(), {"lights.environment.rotate=400"}); },
               {"lights.environment.rotate"});
}

// ---------------------------------------------------------------------------------------------------------
// The distribution and the sampler.

// The fixed-point CDFs: each pixel's probability is the difference of two entries, the last entry is 1,
// and a pixel of 1e-30 next to ones of 1e6 keeps a nonzero probability (2^-24 of its row).
TEST(EnvironmentSampler, FixedPointCdfsReachEveryTexel) {
  lights::EnvironmentMap m = test_map(64, 32);
  m.texels[size_t(10) * 64 + 3] = glm::vec3(1e-30f, 0, 0);
  m.texels[size_t(10) * 64 + 4] = glm::vec3(1e6f);
  const lights::EnvironmentDistribution d = lights::build_distribution(m);
  EXPECT_EQ(d.marginal.back(), 1.f);
  for (uint32_t j = 0; j < m.height; ++j) {
    EXPECT_EQ(d.conditional[size_t(j) * m.width + m.width - 1], 1.f);
    for (uint32_t i = 0; i < m.width; ++i) {
      const size_t k = size_t(j) * m.width + i;
      const float step = d.conditional[k] - (i ? d.conditional[k - 1] : 0.f);
      const bool lit = glm::any(glm::greaterThan(m.texels[k], glm::vec3(0)));
      const bool row_lit = d.marginal[j] > (j ? d.marginal[j - 1] : 0.f);
      if (row_lit) {
        EXPECT_EQ(step > 0, lit) << i << ", " << j;
      }
      EXPECT_EQ(std::ldexp(d.conditional[k], 24), std::round(std::ldexp(d.conditional[k], 24)));
    }
  }
  EXPECT_FLOAT_EQ(d.conditional[size_t(10) * 64 + 3] - d.conditional[size_t(10) * 64 + 2],
                  std::ldexp(1.f, -24));
  // The map's integral over the sphere, against the texels' solid angles summed here.
  double Y = 0;
  for (uint32_t j = 0; j < m.height; ++j)
    for (uint32_t i = 0; i < m.width; ++i) {
      const glm::dvec3 L(m.texels[size_t(j) * m.width + i]);
      Y += (0.2126 * L.r + 0.7152 * L.g + 0.0722 * L.b) * (2 * M_PI / m.width) *
           (std::cos(M_PI * j / m.height) - std::cos(M_PI * (j + 1) / m.height));
    }
  EXPECT_NEAR(d.luminance_integral, Y, 1e-9 * Y);
}

// GPU samples of sample_light() against the map's piecewise-constant density written out above: each pixel
// cut into 2 x 2 cells in (u, v), which must be hit uniformly within the pixel. The map is turned by 37
// degrees; the samples' directions are turned back with this file's own formulas. The densities the shader
// reports (LightSample.pdf and environment_pdf) must equal P(pixel) W H / (2 pi^2 sin theta), and Li the
// pixel's radiance over it.
// Injected defects caught (measured): sin(theta) of the row's centre in Li and the density instead of the
// sample's (pdf and Li wrong in 1.0e6 of the 1.05e6 samples; the furnace below does not see it, z -0.8); the
// turn applied the wrong way round in sample_light (chi2 6.6e7); the conditional CDF read from the row above
// (chi2 1.2e6; the next test's chi2 1.3e6).
TEST(EnvironmentSampler, GpuSamplesFollowTheMapDensity) {
  TempDir dir("haze_lights");
  const uint32_t W = 32, H = 16;
  const double rotate = 37;
  const lights::EnvironmentMap m = test_map(W, H);
  const std::string file = (dir.path() / "map.exr").string();
  lights::write_environment_map(file, m);
  lights::Lights L(context());
  L.update(env_lights(file, float(rotate), 2.f), {});
  const uint32_t n = 1u << 20;
  const auto out = probe(L, {glm::vec4(0.3f, -0.2f, 0.1f, 1)}, n, 11, 0);
  const std::vector<double> P = map_probabilities(m);
  std::vector<double> observed(size_t(4) * W * H, 0.0), expected(observed.size());
  for (size_t k = 0; k < expected.size(); ++k) expected[k] = double(n) * P[k / 4] / 4;
  int pdf_bad = 0, env_pdf_bad = 0, li_bad = 0;
  for (uint32_t s = 0; s < n; ++s) {
    const glm::dvec3 wi(out[3 * s]);
    ASSERT_NEAR(glm::length(wi), 1.0, 1e-5);
    ASSERT_EQ(out[3 * s].w, 1e30f);
    ASSERT_EQ(out[3 * s + 1].w, 0.f);
    const glm::dvec2 uv = map_uv(wi, rotate);
    const uint32_t i = std::min(uint32_t(uv.x * W), W - 1), j = std::min(uint32_t(uv.y * H), H - 1);
    const uint32_t ci = std::min(uint32_t(uv.x * 2 * W), 2 * W - 1) % 2,
                   cj = std::min(uint32_t(uv.y * 2 * H), 2 * H - 1) % 2;
    observed[4 * (size_t(j) * W + i) + 2 * cj + ci] += 1;
    const double sin_theta = std::sin(M_PI * uv.y);
    if (sin_theta < 1e-2) continue;
    // Samples on a pixel border may be attributed to either pixel in float.
    const double fu = uv.x * W - std::floor(uv.x * W), fv = uv.y * H - std::floor(uv.y * H);
    if (std::min({fu, 1 - fu, fv, 1 - fv}) < 1e-3) continue;
    const double pdf = P[size_t(j) * W + i] * W * H / (2 * M_PI * M_PI * sin_theta);
    pdf_bad += std::abs(out[3 * s + 2].x - pdf) > 1e-3 * pdf;
    env_pdf_bad += std::abs(out[3 * s + 2].y - pdf) > 1e-3 * pdf;
    const glm::dvec3 Le = 2.0 * glm::dvec3(m.texels[size_t(j) * W + i]);
    const glm::dvec3 Li(out[3 * s + 1]);
    li_bad += glm::length(Li * pdf - Le) > 1e-3 * glm::length(Le);
  }
  int df = 0;
  const double c = chi2(observed, expected, &df);
  std::cout << "  chi2 " << c << " (df " << df << ", critical " << chi2_critical(df) << ")\n";
  EXPECT_LT(c, chi2_critical(df));
  EXPECT_EQ(pdf_bad, 0);
  EXPECT_EQ(env_pdf_bad, 0);
  EXPECT_EQ(li_bad, 0);
  // Black pixels and the black row are never drawn.
  for (size_t k = 0; k < P.size(); ++k)
    if (P[k] == 0) {
      EXPECT_EQ(observed[4 * k] + observed[4 * k + 1] + observed[4 * k + 2] + observed[4 * k + 3], 0);
    }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// environment_pdf, evaluated by the GPU at world directions (the midpoints of a 4 x 4 grid in (theta, phi)
// over each of the map's pixels, turned by the map's rotation), integrates to 1 over the sphere and gives
// expected counts that the sampler's frequencies must match (chi-square, one cell per pixel). The midpoint
// sums are exact for a density p / sin(theta) over a pixel. (A grid blind to the pixels is not: at the
// sun's pixel borders its error is 1e-3 at 1021 x 509 cells.)
// Injected defects caught (measured): the sampler's turn applied the wrong way round (chi2 5.0e7); the
// conditional CDF read from the row above (chi2 1.3e6).
TEST(EnvironmentSampler, PdfMatchesFrequenciesAndIntegratesToOne) {
  TempDir dir("haze_lights");
  const uint32_t W = 32, H = 16;
  const double rotate = -121;
  const lights::EnvironmentMap m = test_map(W, H, 9);
  const std::string file = (dir.path() / "map.hdr").string();
  lights::write_environment_map(file, m);
  lights::Lights L(context());
  L.update(env_lights(file, float(rotate)), {});

  // Expected count of each pixel: N times the integral of the GPU's pdf over it, by the midpoint rule in
  // (theta, phi) with 4 x 4 points (exact for a density of the form p / sin(theta) over a pixel).
  const int sub = 4;
  std::vector<glm::vec4> dirs;
  for (uint32_t j = 0; j < H; ++j)
    for (uint32_t i = 0; i < W; ++i)
      for (int b = 0; b < sub; ++b)
        for (int a = 0; a < sub; ++a)
          dirs.emplace_back(
              glm::vec3(world_direction((i + (a + 0.5) / sub) / W, (j + (b + 0.5) / sub) / H, rotate)), 0);
  const auto pdf = probe(L, dirs, uint32_t(dirs.size()), 0, 1);
  const uint32_t n = 1u << 20;
  std::vector<double> expected(size_t(W) * H, 0.0), observed(expected.size(), 0.0);
  for (uint32_t j = 0; j < H; ++j)
    for (uint32_t i = 0; i < W; ++i)
      for (int b = 0; b < sub; ++b)
        for (int a = 0; a < sub; ++a) {
          const size_t q = ((size_t(j) * W + i) * sub + b) * sub + a;
          const double theta = M_PI * (j + (b + 0.5) / sub) / H;
          const double dOmega = std::sin(theta) * (M_PI / H / sub) * (2 * M_PI / W / sub);
          expected[size_t(j) * W + i] += double(n) * pdf[3 * q].w * dOmega;
        }
  // The same midpoint sums integrate the density over the sphere.
  double integral = 0;
  for (double e : expected) integral += e / n;
  std::cout << "  integral of environment_pdf over the sphere " << integral << "\n";
  EXPECT_NEAR(integral, 1.0, 4e-5);  // measured 1 - 1.1e-5 (float)
  const auto out = probe(L, {glm::vec4(0, 0, 0, 1)}, n, 12, 0);
  for (uint32_t s = 0; s < n; ++s) {
    const glm::dvec2 uv = map_uv(glm::dvec3(out[3 * s]), rotate);
    observed[size_t(std::min(uint32_t(uv.y * H), H - 1)) * W + std::min(uint32_t(uv.x * W), W - 1)] += 1;
  }
  int df = 0;
  const double c = chi2(observed, expected, &df);
  std::cout << "  chi2 " << c << " (df " << df << ", critical " << chi2_critical(df) << ")\n";
  EXPECT_LT(c, chi2_critical(df));

  EXPECT_EQ(context().validation_messages(), 0u);
}

// ---------------------------------------------------------------------------------------------------------
// The choice of a light.

// Every light type, with powers spread over five orders of magnitude and one of zero.
scene::Lights mixed_lights(const std::string& choice) {
  scene::Lights l;
  float x = 0;
  for (float I : {1.f, 3.f, 10.f, 0.f, 300.f})
    l.points.push_back({glm::vec3(x += 0.3f, 1, 0), glm::vec3(1, 0.5f, 0.2f), I});
  scene::SpotLight sp;
  sp.intensity = 50;
  sp.cone_angle = 40;
  sp.falloff_angle = 10;
  l.spots.push_back(sp);
  l.sun = scene::Sun{};
  l.sun->irradiance = 100;  // as bright as the brightest point: two lights take the others' slots
  l.environment = scene::Environment{};
  l.environment->color = glm::vec3(0.01f);
  l.choice = choice;
  return l;
}
std::vector<lights::Emitter> two_emitters() {
  return {{glm::vec3(0, 2, 0), glm::vec3(1, 2, 0), glm::vec3(0, 2, 1), glm::vec3(4, 4, 4)},
          {glm::vec3(0, 3, 0), glm::vec3(0.01f, 3, 0), glm::vec3(0, 3, 0.01f), glm::vec3(1)}};
}

// The powers by their closed forms; the alias table's probabilities against the shader's rule simulated
// for every one of the 2^24 random numbers, and proportional to power; the uniform table.
// Injected defects caught (measured): the first remainder r0 of each slot taken as 0 in the host's pmf
// (pmf off, e.g. 1.19e-7 against the rule's 5.96e-8); the floor of n on thresholds removed (the 1e-9 light
// gets no value of U).
TEST(LightChoice, AliasTableIsExactAndProportionalToPower) {
  const auto list = lights::light_list(mixed_lights("power"), two_emitters());
  const double r = 2.5;
  const auto w = lights::light_powers(list, 4 * M_PI, r);
  ASSERT_EQ(w.size(), 10u);
  const double Y = glsl::luminance(glm::vec3(1, 0.5f, 0.2f));
  EXPECT_NEAR(w[0], 4 * M_PI * Y, 1e-6);
  EXPECT_NEAR(w[4], 300 * 4 * M_PI * Y, 1e-3);
  EXPECT_EQ(w[3], 0.0);
  // The spot: 50 times the solid angle of its smoothstep falloff, integrated here.
  const double co = std::cos(glm::radians(40.0)), ci = std::cos(glm::radians(30.0));
  const double solid =
      2 * M_PI *
      integrate([&](double mu) { return glsl::smoothstep(float(co), float(ci), float(mu)); }, -1, 1, 200000);
  EXPECT_NEAR(w[5], 50 * solid, 1e-4 * w[5]);
  EXPECT_NEAR(w[6], 2 * M_PI * 4 * 0.5, 1e-5);  // 2 pi L A, two-sided
  EXPECT_NEAR(w[8], 100 * M_PI * r * r, 1e-3);  // the sun: E pi r^2
  EXPECT_NEAR(w[9], 0.01 * 4 * M_PI * M_PI * r * r, 1e-6);

  for (const auto& weights : {w, std::vector<double>{1e-9, 1, 1, 1, 1}, std::vector<double>(7, 1.0),
                              std::vector<double>{0, 0, 0}}) {
    const lights::AliasTable t = lights::alias_table(weights);
    const size_t n = weights.size();
    // The shader's rule, light_choose() in lights.glsl, for every U.
    std::vector<uint64_t> count(n, 0);
    for (uint64_t U = 0; U < lights::kRandomOne; ++U) {
      const uint64_t x = U * n, s = x >> 24, rem = x & 0xffffff;
      ++count[rem < t.threshold[s] ? s : t.alias[s]];
    }
    double total = 0, sum = 0;
    for (double x : weights) total += x;
    for (size_t i = 0; i < n; ++i) {
      EXPECT_EQ(t.pmf[i], double(count[i]) / double(lights::kRandomOne)) << i;
      sum += t.pmf[i];
      if (weights[i] > 0) {
        EXPECT_GT(count[i], 0u) << i;
      }
      if (total > 0 && weights[i] == 0) {
        EXPECT_EQ(count[i], 0u) << i;
      }
      const double want = total > 0 ? weights[i] / total : 1.0 / n;
      // Proportional up to the table's 2^-24 resolution (n units per slot).
      EXPECT_NEAR(t.pmf[i], want, std::max(1e-6 * want, 2.0 * n / lights::kRandomOne)) << i;
    }
    EXPECT_DOUBLE_EQ(sum, 1.0);
  }
}

// The lights the GPU chooses, over 2^20 samples, against the table (chi-square), for power and uniform
// choice; the shader's light_choice_pmf is the table's. Injected defect caught (measured): the alias read
// as alias + 1 (chi2 3.5e8 for the power table).
TEST(LightChoice, GpuChoiceFrequenciesMatchTheTable) {
  for (const char* choice : {"power", "uniform"}) {
    lights::Lights L(context());
    lights::Bounds b;
    b.add(glm::vec3(-2, 0, -2));
    b.add(glm::vec3(2, 3, 2));
    L.update(mixed_lights(choice), two_emitters(), b);
    const size_t n = L.count();
    const uint32_t N = 1u << 20;
    const auto out = probe(L, {glm::vec4(0.2f, 0.5f, 0.1f, 1)}, N, 21, 0);
    std::vector<double> observed(n, 0.0), expected(n);
    for (uint32_t s = 0; s < N; ++s) observed.at(size_t(out[3 * s + 1].w)) += 1;
    const auto pmf = probe(L, std::vector<glm::vec4>(n, glm::vec4(0, 1, 0, 0)), uint32_t(n), 0, 1);
    for (size_t i = 0; i < n; ++i) {
      expected[i] = N * L.choice().pmf[i];
      EXPECT_EQ(pmf[3 * i + 1].x, float(L.choice().pmf[i])) << i;
      if (expected[i] == 0) {
        EXPECT_EQ(observed[i], 0) << i;
      }
    }
    int df = 0;
    const double c = chi2(observed, expected, &df);
    std::cout << "  " << choice << ": chi2 " << c << " (df " << df << ")\n";
    EXPECT_LT(c, chi2_critical(df)) << choice;
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// ---------------------------------------------------------------------------------------------------------
// The map in the renderer.

json map_scene(const std::string& file, double rotate) {
  return {
      {"lights", {{"environment", {{"file", file}, {"rotate", rotate}}}}},
      {"render", {{"width", 16}, {"height", 16}, {"pixel_jitter", false}, {"max_depth", 1}, {"seed", 3}}}};
}

// Camera rays that leave the scene see the map through background(): every pixel equals the texel this
// file's own orientation formulas pick, for a map turned by 90 + 17 degrees. Injected defects caught: u
// mirrored (phi = atan(l.x, l.z)): 1531 of 1531 pixels wrong; the turn's sign flipped in environment_uv:
// 1531.
TEST(EnvironmentMap, BackgroundShowsTheTurnedMap) {
  TempDir dir("haze_lights");
  const uint32_t W = 24, H = 12;
  const double rotate = 107;
  lights::EnvironmentMap m = test_map(W, H, 3);
  const std::string file = (dir.path() / "map.exr").string();
  lights::write_environment_map(file, m);
  json j = map_scene(file, rotate);
  j["camera"] = {{"position", {0, 0, 0}}, {"target", {0.3, 0.4, -1}}, {"fov_y", 120}};
  j["render"]["width"] = 48;
  j["render"]["height"] = 32;
  j["render"]["max_depth"] = 0;
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  EXPECT_TRUE(r.has_feature("ENV_MAP"));
  r.add_samples(1);
  const std::vector<double> acc = r.accum();
  const auto dirs = camera_directions(s);
  int compared = 0, wrong = 0;
  for (size_t p = 0; p < dirs.size(); ++p) {
    const glm::dvec2 uv = map_uv(dirs[p], rotate);
    const double fu = uv.x * W - std::floor(uv.x * W), fv = uv.y * H - std::floor(uv.y * H);
    if (std::min({fu, 1 - fu, fv, 1 - fv}) < 1e-3) continue;
    const glm::vec3 want = m.texels[size_t(uv.y * H) * W + size_t(uv.x * W)];
    const glm::vec3 got(acc[p * glsl::ACC_STRIDE + glsl::ACC_L], acc[p * glsl::ACC_STRIDE + glsl::ACC_L + 1],
                        acc[p * glsl::ACC_STRIDE + glsl::ACC_L + 2]);
    ++compared;
    wrong += glm::length(got - want) > 1e-5f * glm::length(want);
  }
  std::cout << "  " << compared << " pixels compared, " << wrong << " wrong\n";
  EXPECT_GT(compared, int(dirs.size()) * 9 / 10);
  EXPECT_EQ(wrong, 0);
  EXPECT_EQ(context().validation_messages(), 0u);
}

// The white-plane furnace under a sky map with a sun: a Lambertian plane of albedo 1 facing up, seen from
// above, and its radiance, (1 / pi) times the map's cosine-weighted integral over the upper hemisphere:
//   L = (1 / pi) sum over pixels above the horizon of L_ij (2 pi / W) (sin^2 theta_j+1 - sin^2 theta_j) / 2.
struct WhitePlaneFurnace {
  json scene;
  glm::dvec3 radiance;
};

WhitePlaneFurnace white_plane_furnace(const TempDir& dir) {
  const uint32_t W = 64, H = 32;
  lights::SkyParams sp;
  sp.width = W;
  sp.height = H;
  sp.sun_size = 12;
  sp.sun_radiance = 30;
  const lights::EnvironmentMap m = lights::make_sky(sp);
  const std::string file = (dir.path() / "sky.exr").string();
  lights::write_environment_map(file, m);
  glm::dvec3 E(0);
  for (uint32_t j = 0; j < H / 2; ++j) {
    const double a = std::sin(M_PI * j / H), b = std::sin(M_PI * (j + 1) / H);
    for (uint32_t i = 0; i < W; ++i)
      E += glm::dvec3(m.texels[size_t(j) * W + i]) * (2 * M_PI / W) * (b * b - a * a) / 2.0;
  }
  json j = map_scene(file, 25);
  j["camera"] = {{"position", {0, 1, 0}}, {"target", {0.2, 0, -0.3}}, {"up", {0, 0, -1}}, {"fov_y", 50}};
  j["surfaces"] = {{{"mesh", {{"kind", "plane"}, {"size", {40, 40}}}},
                    {"albedo", {1, 1, 1}},
                    {"transform", {{"rotate", {-90, 0, 0}}}}}};
  return {j, E / M_PI};
}

// A white furnace with a non-constant map (white_plane_furnace): the same radiance at every point and for
// every view. NEE alone carries the map (max_depth 1).
// Injected defects caught (measured): the 2 pi^2 of the density replaced by 2 pi in Li (pooled z -355);
// Li multiplied by the light count instead of divided by the choice's pmf, with the point light present
// (pooled z -24).
TEST(EnvironmentMap, WhitePlaneFurnaceReflectsTheCosineWeightedMap) {
  TempDir dir("haze_lights");
  const WhitePlaneFurnace f = white_plane_furnace(dir);
  const glm::dvec3 ref = f.radiance;
  json j = f.scene;
  // A point light under the plane: it lights nothing the camera sees, but takes about half of the choice.
  j["lights"]["points"] = {{{"position", {0, -1, 0}}, {"intensity", 1000}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(256);
  std::cout << "  P(choose the map) " << r.lights().choice().pmf[1] << "\n";
  std::cout << "  reference " << ref.r << " " << ref.g << " " << ref.b << "\n";
  for (int c = 0; c < 3; ++c)
    expect_z(z_test(r, glsl::ACC_L + c, glsl::ACC_L2 + c, std::vector<double>(256, ref[c])),
             fmt::format("channel {}", c));
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Single scattering of the map in a thin slab (sigma_t 0.6, albedo 0.8, isotropic), seen from below: the
// volume term of each pixel against the CPU integral
//   int_0^1 dy / d_y exp(-sigma y / d_y) sigma albedo I(y),
//   I(y) = 1 / (4 pi) sum_ij L_ij (2 pi / W) int over the row's cos theta of exp(-sigma l(y, mu)) dmu,
// l the path to the slab's face. Injected defect caught (measured): theta taken from -y in sample_light
// (cos theta negated: the ground lights the slab from above; pooled z 29 to 36 per channel).
TEST(EnvironmentMap, NeeInAThinSlabMatchesTheCpuIntegral) {
  TempDir dir("haze_lights");
  const uint32_t W = 32, H = 16;
  lights::SkyParams sp;
  sp.width = W;
  sp.height = H;
  sp.sun_size = 20;
  sp.sun_radiance = 20;
  sp.sun_elevation = 20;
  const lights::EnvironmentMap m = lights::make_sky(sp);
  const std::string file = (dir.path() / "sky.hdr").string();
  lights::write_environment_map(file, m);
  const lights::EnvironmentMap read = lights::read_environment_map(file);  // RGBE-rounded texels
  const double sigma = 0.6, albedo = 0.8;
  json j = map_scene(file, 30);  // a turn about +y changes nothing in an infinite slab
  j["camera"] = {{"position", {0, -1, 0}}, {"target", {0, 1, 0}}, {"up", {0, 0, 1}}, {"fov_y", 40}};
  j["haze"] = {{"sigma_t", sigma}, {"albedo", {albedo, albedo, albedo}}, {"g", 0},
               {"bounded", true},  {"bounds_min", {-100, 0, -100}},      {"bounds_max", {100, 1, 100}}};
  scene::Scene s = make_scene(j);
  render::Renderer r(context(), s);
  r.add_samples(128);

  // I(y) on a grid of y, per channel.
  const int ny = 200;
  std::vector<glm::dvec3> I(ny + 1, glm::dvec3(0));
  for (uint32_t row = 0; row < H; ++row) {
    glm::dvec3 Lrow(0);
    for (uint32_t i = 0; i < W; ++i) Lrow += glm::dvec3(read.texels[size_t(row) * W + i]);
    const double mu1 = std::cos(M_PI * row / H), mu0 = std::cos(M_PI * (row + 1) / H);
    for (int k = 0; k <= ny; ++k) {
      const double y = double(k) / ny;
      const double t = integrate(
          [&](double mu) {
            const double l = mu > 0 ? (1 - y) / mu : (mu < 0 ? y / -mu : 1e30);
            return std::exp(-sigma * l);
          },
          mu0, mu1, 2000);
      I[k] += Lrow * (2 * M_PI / W) * t / (4 * M_PI);
    }
  }
  auto I_at = [&](double y) {
    const double x = std::clamp(y, 0.0, 1.0) * ny;
    const int k = std::min(int(x), ny - 1);
    return glm::mix(I[k], I[k + 1], x - k);
  };
  const auto dirs = camera_directions(s);
  for (int c = 0; c < 3; ++c) {
    std::vector<double> ref;
    for (const auto& d : dirs)
      ref.push_back(
          integrate([&](double y) { return std::exp(-sigma * y / d.y) * sigma * albedo * I_at(y)[c]; }, 0, 1,
                    2000) /
          d.y);
    expect_z(z_test(r, glsl::ACC_VOL + c, glsl::ACC_VOL2 + c, ref), fmt::format("channel {}", c));
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Choosing lights by power changes which light is sampled, not what converges: the same scene with power
// and uniform choice (different seeds), per pixel and channel z of the difference. Injected defect caught
// (measured): Li multiplied by the light count instead of divided by the pmf (pooled z 64).
TEST(LightChoice, PowerAndUniformChoiceAgree) {
  TempDir dir("haze_lights");
  lights::SkyParams sp;
  sp.width = 32;
  sp.height = 16;
  const std::string file = (dir.path() / "sky.exr").string();
  lights::write_environment_map(file, lights::make_sky(sp));
  auto render = [&](const char* choice, uint32_t seed) {
    json j = map_scene(file, 0);
    j["lights"]["environment"]["intensity"] = 0.05;
    j["lights"]["choice"] = choice;
    j["lights"]["points"] = json::array();
    for (int k = 0; k < 6; ++k)
      j["lights"]["points"].push_back(
          {{"position", {-1.5 + 0.6 * k, 1.5, -0.5}}, {"intensity", k == 2 ? 40 : 0.5}});
    j["lights"]["sun"] = {{"direction", {0.3, 1, 0.2}}, {"irradiance", 0.5}};
    j["camera"] = {{"position", {0, 0.8, 4}}, {"target", {0, 0.8, 0}}, {"fov_y", 50}};
    j["haze"] = {{"sigma_t", 0.3},  {"albedo", {0.9, 0.8, 0.7}}, {"g", 0.3},
                 {"bounded", true}, {"bounds_min", {-2, 0, -2}}, {"bounds_max", {2, 2, 2}}};
    j["render"]["seed"] = seed;
    auto r = std::make_unique<render::Renderer>(context(), make_scene(j));
    r->add_samples(256);
    return r;
  };
  const auto a = render("power", 1), b = render("uniform", 2);
  for (int c = 0; c < 3; ++c) {
    const Estimate ea = estimate(*a, glsl::ACC_L + c, glsl::ACC_L2 + c),
                   eb = estimate(*b, glsl::ACC_L + c, glsl::ACC_L2 + c);
    std::vector<double> diff, var;
    for (size_t p = 0; p < ea.mean.size(); ++p) {
      diff.push_back(ea.mean[p] - eb.mean[p]);
      var.push_back(ea.var_of_mean[p] + eb.var_of_mean[p]);
    }
    expect_z(z_test(diff, var), fmt::format("channel {}", c));
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// Maps at the extremes of what is valid: 1x1, one row, all black, light only in the rows at the poles (where
// sin(theta) vanishes), a texel of 1e30 among ones with intensity 1e4, intensity 0, and power choice next to
// a light 1e8 times brighter. Every layer stays finite and no sample is discarded (non-finite, step cap,
// majorant). A guard: of the defects injected, none was caught by this test alone (a black map's CDF left as
// 0/0 renders black anyway).
TEST(EnvironmentMap, ExtremeMapsStayFinite) {
  TempDir dir("haze_lights");
  struct Case {
    const char* name;
    uint32_t w, h;
    std::function<glm::vec3(uint32_t, uint32_t)> texel;
    double intensity;
  };
  const std::vector<Case> cases = {
      {"1x1", 1, 1, [](uint32_t, uint32_t) { return glm::vec3(0.5f, 1, 2); }, 1},
      {"one row", 4, 1, [](uint32_t i, uint32_t) { return glm::vec3(float(i)); }, 1},
      {"black", 8, 4, [](uint32_t, uint32_t) { return glm::vec3(0); }, 1},
      {"poles", 16, 64, [](uint32_t, uint32_t j) { return glm::vec3(j == 0 || j == 63 ? 5.f : 0.f); }, 1},
      {"hot texel", 64, 32,
       [](uint32_t i, uint32_t j) { return glm::vec3(i == 40 && j == 10 ? 1e30f : 1.f); }, 1e4},
      {"intensity 0", 8, 4, [](uint32_t, uint32_t) { return glm::vec3(1); }, 0},
  };
  for (const Case& c : cases) {
    lights::EnvironmentMap m;
    m.width = c.w;
    m.height = c.h;
    for (uint32_t j = 0; j < c.h; ++j)
      for (uint32_t i = 0; i < c.w; ++i) m.texels.push_back(c.texel(i, j));
    const std::string file = (dir.path() / "m.exr").string();
    lights::write_environment_map(file, m);
    json j = map_scene(file, 10);
    j["lights"]["environment"]["intensity"] = c.intensity;
    j["lights"]["points"] = {{{"position", {0, 1, 0}}, {"intensity", 1e8}}};
    j["camera"] = {{"position", {0, 0.6, 3}}, {"target", {0, 0.3, 0}}, {"fov_y", 70}};
    j["haze"] = {{"sigma_t", 0.3},
                 {"albedo", {0.9, 0.9, 0.9}},
                 {"bounded", true},
                 {"bounds_min", {-1, 0, -1}},
                 {"bounds_max", {1, 1, 1}}};
    j["surfaces"] = {
        {{"mesh", {{"kind", "plane"}, {"size", {4, 4}}}}, {"transform", {{"rotate", {-90, 0, 0}}}}}};
    j["render"]["max_depth"] = 3;
    render::Renderer r(context(), make_scene(j));
    r.add_samples(4);
    const render::Image img = r.resolve();
    int bad = 0;
    for (float x : img.data) bad += !std::isfinite(x);
    for (double x : r.accum()) bad += !std::isfinite(x);
    EXPECT_EQ(bad, 0) << c.name;
    EXPECT_EQ(img.counters.discarded(), 0u) << c.name;
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// ---------------------------------------------------------------------------------------------------------
// MIS between light sampling and the walk's phase/BSDF sampling (render.mis): walk rays that escape to the
// environment or hit an emissive triangle add their power-heuristic share, NEE the complementary one.

// The white-plane furnace of the map (above) with a bounce: the plane's walk rays escape to the map, so with
// MIS half of what converges comes from them and the closed form must still hold, for both estimators.
// Injected defects caught (measured, per channel, both estimators): the escaping walk ray's MIS weight
// dropped (w = 1: the map counted by both strategies): pooled z +30 to +40; NEE's weight dropped: +129 to
// +166.
TEST(LightMis, WhitePlaneFurnaceWithEscapingWalks) {
  TempDir dir("haze_lights");
  const WhitePlaneFurnace f = white_plane_furnace(dir);
  const glm::dvec3 ref = f.radiance;
  for (const char* estimator : {"default", "volpath"}) {
    json j = f.scene;
    j["render"]["max_depth"] = 2;
    j["render"]["estimator"] = estimator;
    scene::Scene s = make_scene(j);
    render::Renderer r(context(), s);
    EXPECT_TRUE(r.has_feature("MIS")) << estimator;
    r.add_samples(256);
    EXPECT_EQ(r.resolve().counters.discarded(), 0u);
    for (int c = 0; c < 3; ++c)
      expect_z(z_test(r, glsl::ACC_L + c, glsl::ACC_L2 + c, std::vector<double>(256, ref[c])),
               fmt::format("{} channel {}", estimator, c));
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

// A floor, an emissive panel above it and a hazy box under a map with a sun, multiple scattering: with
// render.mis "nee" only light sampling reaches the map and the panel, with "power" the walk's phase and
// cosine sampling too. Both converge to the same image, per pixel and channel, in the surface term (surface
// vertices: cosine sampling) and the volume term (medium vertices: phase sampling), for both estimators.
// The panel stays out of the haze: NEE alone to an area light from medium points next to it has infinite
// variance (the second moment grows like 1 / h^2 at a height h above it), so no z-test could judge it.
// Injected defects caught (measured, pooled z per channel of the surface / volume terms, default and
// volpath): the escaping walk ray's weight dropped: -30 to -35 / -22 to -29 and -28 to -32 / -15 to -19;
// NEE's weight dropped: -47 to -82 / -22 to -47 and -36 to -70 / -13 to -24; the weight of a walk ray
// that hits the panel dropped: -4.8 to -11 / -5.5 to -7.8 and -2.6 to -8.2 / -3.1 to -4.7.
void mis_check_nee_against_power(const std::string& estimator) {
  TempDir dir("haze_lights");
  const std::string file = (dir.path() / "map.exr").string();
  lights::write_environment_map(file, test_map(32, 16, 7));
  json j = map_scene(file, 40);
  j["camera"] = {{"position", {0, 1.2, 3}}, {"target", {0, 0.3, 0}}, {"fov_y", 50}};
  j["surfaces"] = {{{"mesh", {{"kind", "plane"}, {"size", {6, 6}}}},
                    {"albedo", {0.7, 0.6, 0.5}},
                    {"transform", {{"rotate", {-90, 0, 0}}}}},
                   {{"mesh", {{"kind", "plane"}, {"size", {0.8, 0.8}}}},
                    {"emission", {4, 3, 2}},
                    {"transform", {{"translate", {0.4, 1.7, -0.2}}, {"rotate", {60, 20, 0}}}}}};
  j["haze"] = {{"sigma_t", 0.8},  {"albedo", {0.9, 0.85, 0.8}}, {"g", 0.4},
               {"bounded", true}, {"bounds_min", {-1, 0, -1}},  {"bounds_max", {0.5, 1.2, 1}}};
  j["render"]["width"] = 12;
  j["render"]["height"] = 10;
  j["render"]["max_depth"] = 3;
  j["render"]["estimator"] = estimator;
  auto run = [&](const char* mis, uint32_t seed, int spp) {
    json k = j;
    k["render"]["mis"] = mis;
    k["render"]["seed"] = seed;
    render::Renderer r(context(), make_scene(k));
    EXPECT_EQ(r.has_feature("MIS"), std::string(mis) == "power") << estimator;
    r.add_samples(spp);
    expect_no_discards(r.resolve().counters, estimator + " " + mis);
    return std::pair{estimate(r, glsl::ACC_SURF, glsl::ACC_SURF2, 3),
                     estimate(r, glsl::ACC_VOL, glsl::ACC_VOL2, 3)};
  };
  const auto [ns, nv] = run("nee", 11, 1024);
  const auto [ps, pv] = run("power", 12, 1024);
  auto mean_var = [](const Estimate& e) {
    double v = 0;
    for (double x : e.var_of_mean) v += x;
    return v;
  };
  std::cout << "  " << estimator << ": variance nee / power, surface term " << mean_var(ns) / mean_var(ps)
            << ", volume term " << mean_var(nv) / mean_var(pv) << "\n";
  expect_unbiased(two_sample_test(ns, ps), estimator + ": surface term, nee against power");
  expect_unbiased(two_sample_test(nv, pv), estimator + ": volume term, nee against power");
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(LightMis, NeeOnlyAndMisAgreeDefault) {
  mis_check_nee_against_power("default");
}
TEST(LightMis, NeeOnlyAndMisAgreeVolpath) {
  mis_check_nee_against_power("volpath");
}

// ---------------------------------------------------------------------------------------------------------
// Costs and reuse.

// A map is a feature with three buffers in the ledger (texels and both CDFs, at their sizes); a constant
// environment has none of them and no map code; the file is read again only when it changes; replaced
// texels are a note of the renderer.
TEST(EnvironmentMap, BuffersOnlyForAMapAndReadOnlyWhenTheFileChanges) {
  TempDir dir("haze_lights");
  const uint32_t W = 16, H = 8;
  lights::EnvironmentMap m = test_map(W, H);
  const std::string file = (dir.path() / "map.exr").string();
  lights::write_environment_map(file, m);
  auto count_env = [] {
    uint64_t bytes = 0;
    int n = 0;
    for (const auto& e : context().ledger().entries())
      if (e.name.rfind("environment ", 0) == 0) ++n, bytes += e.requested;
    return std::pair{n, bytes};
  };
  {
    json j = map_scene(file, 0);
    j["lights"]["environment"] = {{"color", {1, 1, 1}}};
    render::Renderer r(context(), make_scene(j));
    EXPECT_TRUE(r.has_feature("ENV"));
    EXPECT_FALSE(r.has_feature("ENV_MAP"));
    EXPECT_EQ(count_env().first, 0);
  }
  lights::Lights L(context());
  L.update(env_lights(file, 0), {});
  EXPECT_EQ(L.map_reads(), 1);
  EXPECT_EQ(count_env(), (std::pair{3, uint64_t(W) * H * 12 + uint64_t(W) * H * 4 + H * 4}));
  L.update(env_lights(file, 45, 3.f), {});  // turn and intensity: the same file
  EXPECT_EQ(L.map_reads(), 1);
  m.texels[0] = glm::vec3(NAN);
  lights::write_environment_map(file, m);
  std::filesystem::last_write_time(file, std::filesystem::last_write_time(file) + std::chrono::seconds(2));
  L.update(env_lights(file, 45, 3.f), {});
  EXPECT_EQ(L.map_reads(), 2);
  ASSERT_EQ(L.notes().size(), 1u);
  EXPECT_NE(L.notes()[0].find("3 texel channels replaced by 0 (3 NaN"), std::string::npos) << L.notes()[0];
  EXPECT_NE(L.notes()[0].find(file), std::string::npos);
  L.update(scene::Lights{}, {});
  EXPECT_FALSE(L.has_map());
  EXPECT_EQ(count_env().first, 0);

  render::Renderer r(context(), make_scene(map_scene(file, 0)));
  const auto notes = r.notes();
  EXPECT_EQ(std::count_if(notes.begin(), notes.end(),
                          [](const std::string& n) { return n.find("NaN") != std::string::npos; }),
            1);
}

}  // namespace
}  // namespace haze::test
