// Volume motion vectors (guiding/volume_motion.hpp) against a CPU reference in double precision: virtual
// points on a plane seen by a camera that moves, several points landing on one pixel (the nearest must
// win), points carried by moving media, odd image sizes. Expected values are worked out on the host;
// thresholds were fixed before looking at results.
#include "guiding/volume_motion.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <glm/gtc/matrix_transform.hpp>
#include <iostream>
#include <limits>
#include <memory>
#include <optional>

#include "render/renderer.hpp"
#include "shaders/glsl.hpp"
#include "test_util.hpp"

namespace haze::test {
namespace {

using glsl::MediumMotion;

constexpr double kMotionTol = 1e-3;  // pixels
constexpr double kDeltaTol = 1e-4;   // scene units (distances ~5)

// A pinhole camera with unit axes and the tangents of its half angles (image y runs down).
struct Cam {
  glm::dvec3 pos{0}, right{1, 0, 0}, up{0, 1, 0}, fwd{0, 0, 1};
  double tan_x = 0.6, tan_y = 0.4;
};

glm::dvec3 ray(const Cam& c, glm::dvec2 pixel, glm::dvec2 size) {
  glm::dvec2 ndc = pixel / size * 2.0 - 1.0;
  return glm::normalize(c.fwd + ndc.x * c.tan_x * c.right - ndc.y * c.tan_y * c.up);
}

std::optional<glm::dvec2> project(const Cam& c, glm::dvec3 X, glm::dvec2 size) {
  glm::dvec3 v = X - c.pos;
  double z = glm::dot(v, c.fwd);
  if (z <= 0) return std::nullopt;
  glm::dvec2 ndc(glm::dot(v, c.right) / z / c.tan_x, -glm::dot(v, c.up) / z / c.tan_y);
  return (ndc + 1.0) * 0.5 * size;
}

// A medium box moving by `shift` between the frames.
struct Box {
  glm::dvec3 lo, hi, shift;
};

struct Case {
  int W, H;
  Cam prev, cur;
  std::vector<float> depth;  // per previous pixel
  std::vector<Box> media;

  Case(int w, int h, double tan_y = 0.4) : W(w), H(h), depth(size_t(w) * h, 0.f) {
    prev.tan_y = cur.tan_y = tan_y;
    prev.tan_x = cur.tan_x = tan_y * w / h;
  }
  glm::dvec2 size() const { return {W, H}; }
  glm::dvec3 prev_ray(int x, int y) const { return ray(prev, glm::dvec2(x + 0.5, y + 0.5), size()); }
  // Every previous pixel's point on the plane z = z0.
  void plane(double z0) {
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        glm::dvec3 d = prev_ray(x, y);
        depth[size_t(y) * W + x] = float((z0 - prev.pos.z) / d.z);
      }
  }
  // World x of the plane z = z0 at the previous image's column edge `px` (and y at row edge `py`): box
  // faces there are half a pixel from every point, so no rounding can change which box holds a point.
  double edge_x(double z0, double px) const { return z0 * prev.tan_x * (px / W * 2 - 1); }
  double edge_y(double z0, double py) const { return -z0 * prev.tan_y * (py / H * 2 - 1); }
  // Pixel shift of the camera moving sideways by t, seen on the plane z = z0 (prev camera at the origin).
  double pixels_per_unit_x(double z0) const { return W / (2 * z0 * prev.tan_x); }
  double pixels_per_unit_y(double z0) const { return H / (2 * z0 * prev.tan_y); }
};

glsl::GpuScene gpu_scene(const Case& s) {
  glsl::GpuScene g{};
  auto set = [](const Cam& c, glm::vec4& pos, glm::vec4& right, glm::vec4& up, glm::vec4& fwd) {
    pos = glm::vec4(glm::vec3(c.pos), 0);
    right = glm::vec4(glm::vec3(c.right * c.tan_x), 0);
    up = glm::vec4(glm::vec3(c.up * c.tan_y), 0);
    fwd = glm::vec4(glm::vec3(c.fwd), 0);
  };
  set(s.cur, g.cam_position, g.cam_right, g.cam_up, g.cam_forward);
  set(s.prev, g.prev_cam_position, g.prev_cam_right, g.prev_cam_up, g.prev_cam_forward);
  g.size = glm::uvec4(s.W, s.H, 1, 1);
  return g;
}

// The G-buffer's surface motion, a pattern no point motion reproduces.
glm::vec2 surface_motion(int x, int y) {
  return {0.25f * x - 3.f, 0.5f * y + 1.f};
}

struct Expected {
  std::vector<glm::dvec4> value;  // per pixel, as the pass should write it
  std::vector<int> source;        // winning source pixel, -1: none
  int landed = 0;
  bool ambiguous = false;  // a point within rounding of a pixel edge, a box face or a tie: a bad setup
};

Expected reference(const Case& s) {
  const size_t n = size_t(s.W) * s.H;
  Expected e;
  e.value.resize(n);
  e.source.assign(n, -1);
  std::vector<double> best(n, std::numeric_limits<double>::infinity());
  for (int y = 0; y < s.H; ++y)
    for (int x = 0; x < s.W; ++x) {
      const size_t p = size_t(y) * s.W + x;
      const double d = s.depth[p];
      if (!(d > 0) || !std::isfinite(d)) continue;
      glm::dvec3 X = s.prev.pos + d * s.prev_ray(x, y);
      for (const Box& b : s.media) {
        glm::dvec3 m = glm::min(glm::abs(X - b.lo), glm::abs(X - b.hi));
        if (glm::min(m.x, glm::min(m.y, m.z)) < 1e-4) e.ambiguous = true;
        if (glm::all(glm::greaterThanEqual(X, b.lo)) && glm::all(glm::lessThanEqual(X, b.hi))) {
          X += b.shift;
          break;
        }
      }
      std::optional<glm::dvec2> q = project(s.cur, X, s.size());
      if (!q || q->x < 0 || q->y < 0 || q->x >= s.W || q->y >= s.H) continue;
      glm::dvec2 f = *q - glm::floor(*q);
      if (glm::min(glm::min(f.x, 1 - f.x), glm::min(f.y, 1 - f.y)) < 1e-4) e.ambiguous = true;
      const size_t t = size_t(std::floor(q->y)) * s.W + size_t(std::floor(q->x));
      const double dist = glm::length(X - s.cur.pos);
      if (std::abs(dist - best[t]) < 1e-5) e.ambiguous = true;
      if (dist < best[t]) {
        best[t] = dist;
        e.source[t] = int(p);
        e.value[t] = glm::dvec4(glm::dvec2(x + 0.5, y + 0.5) - *q, dist - d, 1);
      }
    }
  for (int y = 0; y < s.H; ++y)
    for (int x = 0; x < s.W; ++x) {
      const size_t t = size_t(y) * s.W + x;
      if (e.source[t] >= 0)
        ++e.landed;
      else
        e.value[t] = glm::dvec4(glm::dvec2(surface_motion(x, y)), 0, 0);
    }
  return e;
}

// Runs the pass on a Case, on `vm` when given (a new instance otherwise). The depth sits at offset 1 of 3
// floats per pixel (the others hold garbage), as when the caller points into a layer of a wider buffer.
std::vector<glm::vec4> run(const Case& s, guiding::VolumeMotion* vm = nullptr,
                           bool media_buffer_without_media = false, gpu::Timer* timer = nullptr) {
  gpu::Context& ctx = context();
  const size_t n = size_t(s.W) * s.H;
  glsl::GpuScene gs = gpu_scene(s);
  gpu::Buffer scene(ctx, "test scene", "test", sizeof(gs), "GpuScene");
  scene.upload(&gs, sizeof(gs));

  std::vector<float> depth(n * 3, std::numeric_limits<float>::quiet_NaN());
  for (size_t p = 0; p < n; ++p) {
    depth[p * 3 + 1] = s.depth[p];
    depth[p * 3 + 2] = -1.f;
  }
  gpu::Buffer prev_depth(ctx, "test previous depth", "test", depth.size() * 4, "3 x f32");
  prev_depth.upload(depth);

  // The G-buffer layer g_normal: (octahedral normal, motion).
  std::vector<glm::vec4> g(n, glm::vec4(0.f));
  for (int y = 0; y < s.H; ++y)
    for (int x = 0; x < s.W; ++x) {
      glm::vec2 m = surface_motion(x, y);
      g[size_t(y) * s.W + x] = glm::vec4(0.f, 0.f, m.x, m.y);
    }
  static_assert(glsl::G_MOTION % 4 == 2);
  gpu::Buffer gbuffer(ctx, "test g-buffer g_normal", "test", g.size() * 16, "4 x f32");
  gbuffer.upload(g);

  std::vector<MediumMotion> media;
  for (const Box& b : s.media)
    media.push_back({glm::translate(glm::mat4(1), glm::vec3(b.shift)), glm::vec4(glm::vec3(b.lo), 0),
                     glm::vec4(glm::vec3(b.hi), 0)});
  // An entry that would move every point, passed with count 0: nothing may move.
  if (media.empty() && media_buffer_without_media)
    media.push_back({glm::translate(glm::mat4(1), glm::vec3(5)), glm::vec4(-100), glm::vec4(100)});
  gpu::Buffer media_buf;
  if (!media.empty()) {
    media_buf = gpu::Buffer(ctx, "test media motion", "test", media.size() * sizeof(MediumMotion));
    media_buf.upload(media);
  }

  std::unique_ptr<guiding::VolumeMotion> own;
  if (!vm) vm = (own = std::make_unique<guiding::VolumeMotion>(ctx, s.W, s.H)).get();
  guiding::VolumeMotionInputs in{
      &scene, &prev_depth, 3, 1, &gbuffer, media.empty() ? nullptr : &media_buf, uint32_t(s.media.size())};
  ctx.submit_and_wait([&](VkCommandBuffer cmd) {
    if (timer) timer->reset(cmd);
    vm->run(cmd, timer, in);
  });
  return vm->download();
}

// Compares the pass's output with the reference; returns the number of mismatching pixels.
int compare(const Case& s, const std::vector<glm::vec4>& out, const Expected& e) {
  int bad = 0;
  for (int y = 0; y < s.H; ++y)
    for (int x = 0; x < s.W; ++x) {
      const size_t t = size_t(y) * s.W + x;
      const glm::dvec4 got(out[t]), want = e.value[t];
      bool ok = got.w == want.w;
      if (want.w > 0)
        ok = ok && std::abs(got.x - want.x) < kMotionTol && std::abs(got.y - want.y) < kMotionTol &&
             std::abs(got.z - want.z) < kDeltaTol;
      else
        ok = ok && got == want;  // the surface motion, copied
      if (!ok && ++bad <= 5)
        ADD_FAILURE() << "pixel (" << x << ", " << y << "): got " << got.x << ", " << got.y << ", " << got.z
                      << ", " << got.w << "; want " << want.x << ", " << want.y << ", " << want.z << ", "
                      << want.w << " (source " << e.source[t] << ")";
    }
  return bad;
}

TEST(VolumeMotion, PlanePointsMatchTheAnalyticMotion) {
  // The camera moves sideways parallel to the plane z = 5: every point moves by the same disparity.
  const double z0 = 5, disparity = 2.37;  // pixels, fraction well away from pixel edges
  Case s(37, 23);
  s.plane(z0);
  s.cur.pos = glm::dvec3(disparity / s.pixels_per_unit_x(z0), 0, 0);
  // Pixels without a point: zero, negative, infinite and NaN depths.
  s.depth[3] = 0.f;
  s.depth[40] = -2.f;
  s.depth[41] = std::numeric_limits<float>::infinity();
  s.depth[100] = std::numeric_limits<float>::quiet_NaN();
  Expected e = reference(s);
  ASSERT_FALSE(e.ambiguous);

  gpu::Timer timer(context());
  guiding::VolumeMotion vm(context(), s.W, s.H);
  std::vector<glm::vec4> out = run(s, &vm, false, &timer);
  EXPECT_EQ(compare(s, out, e), 0);
  // Independently of the reference: the analytic motion (disparity, 0) and distance change.
  int landed = 0;
  for (int y = 0; y < s.H; ++y)
    for (int x = 0; x < s.W; ++x) {
      const glm::vec4 m = out[size_t(y) * s.W + x];
      if (m.w == 0) continue;
      ++landed;
      EXPECT_NEAR(m.x, disparity, kMotionTol);
      EXPECT_NEAR(m.y, 0, kMotionTol);
      // The point that landed here came from column x + 2; its distance from either camera.
      glm::dvec3 X = double(s.depth[size_t(y) * s.W + x + 2]) * s.prev_ray(x + 2, y);
      EXPECT_NEAR(m.z, glm::length(X - s.cur.pos) - glm::length(X), kDeltaTol);
    }
  // The last 2 columns receive nothing (the first 2 columns' points left through the left edge), nor do
  // the 4 pixels whose source had no point.
  EXPECT_EQ(landed, (s.W - 2) * s.H - 4);
  EXPECT_EQ(landed, e.landed);

  // Its buffers in the memory ledger: the output and the keys.
  const uint64_t pixels = uint64_t(s.W) * s.H;
  int found = 0;
  for (const gpu::LedgerEntry& l : context().ledger().entries()) {
    if (l.name == "volume motion" && l.category == "volume motion" && l.requested == pixels * 16) ++found;
    if (l.name == "volume motion keys" && l.category == "per-frame temporaries" && l.requested == pixels * 8)
      ++found;
  }
  EXPECT_EQ(found, 2);

  auto times = timer.read_ms();
  ASSERT_EQ(times.size(), 1u);
  EXPECT_EQ(times[0].first, "volume_motion");
  std::cout << "  volume_motion " << s.W << "x" << s.H << ": " << times[0].second << " ms\n";

  // A rotated and translated camera, against the reference only.
  s.cur.pos = glm::dvec3(0.3, -0.2, 0.4);
  glm::dmat3 r =
      glm::dmat3(glm::rotate(glm::dmat4(1), glm::radians(4.0), glm::normalize(glm::dvec3(1, 2, 0))));
  s.cur.right = r * s.cur.right;
  s.cur.up = r * s.cur.up;
  s.cur.fwd = r * s.cur.fwd;
  e = reference(s);
  ASSERT_FALSE(e.ambiguous);
  EXPECT_GT(e.landed, s.W * s.H / 2);
  EXPECT_EQ(compare(s, run(s), e), 0);
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(VolumeMotion, NearestPointWinsDeterministically) {
  const double z0 = 5;
  for (double disparity : {2.37, -2.37}) {
    Case s(37, 23);
    s.plane(z0);
    const double ppu = s.pixels_per_unit_x(z0);
    s.cur.pos = glm::dvec3(disparity / ppu, 0, 0);
    // In rows 5 and 17 (and row 12, across workgroups), 11 sources at different depths all land on column
    // `target` (+0.5): a source at x moves by x + 0.5 - target pixels, i.e. sits at depth
    // z = (camera shift) * ppu * z0 / (x - target + 0.5). The nearest has the largest shift.
    const int target = disparity > 0 ? 5 : 30;
    const int first = disparity > 0 ? 10 : 0;
    for (int y : {5, 12, 17})
      for (int x = first; x < first + 11; ++x) {
        const double shift = x + 0.5 - (target + 0.5);
        const glm::dvec3 d = s.prev_ray(x, y);
        const double z = disparity * z0 / shift;
        s.depth[size_t(y) * s.W + x] = float(z / d.z);
      }
    Expected e = reference(s);
    ASSERT_FALSE(e.ambiguous);
    // Moving right, the nearest point came from the right end (highest index); moving left, from the left
    // end (lowest index): neither the first nor the last writer by index.
    const int nearest = disparity > 0 ? first + 10 : first;
    for (int y : {5, 12, 17}) {
      ASSERT_EQ(e.source[size_t(y) * s.W + target], y * s.W + nearest);
    }

    guiding::VolumeMotion vm(context(), s.W, s.H);
    std::vector<glm::vec4> out = run(s, &vm);
    EXPECT_EQ(compare(s, out, e), 0);
    for (int y : {5, 12, 17}) {
      const glm::vec4 m = out[size_t(y) * s.W + target];
      EXPECT_EQ(m.w, 1.f);
      EXPECT_NEAR(m.x, nearest - target, kMotionTol) << "disparity " << disparity << " row " << y;
    }
    for (int i = 0; i < 4; ++i) {
      std::vector<glm::vec4> again = run(s, i % 2 ? &vm : nullptr);
      EXPECT_EQ(0, std::memcmp(again.data(), out.data(), out.size() * sizeof(glm::vec4))) << "run " << i;
    }
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(VolumeMotion, MovingMediaCarryTheirPoints) {
  const double z0 = 5, disparity = 2.37;
  Case s(37, 23);
  s.plane(z0);
  const double ppx = s.pixels_per_unit_x(z0), ppy = s.pixels_per_unit_y(z0);
  s.cur.pos = glm::dvec3(disparity / ppx, 0, 0);
  // Boxes in pixel units of the previous image (faces on pixel edges). A moves by (+1.25, -0.6) pixels, B
  // (which overlaps A; A comes first, so A moves the shared points) by (-0.5, +1.3), C goes behind the
  // camera (its points are dropped, not mirrored back into the image).
  auto box = [&](double x0, double x1, double y0, double y1, glm::dvec3 shift) {
    return Box{glm::dvec3(s.edge_x(z0, x0), s.edge_y(z0, y1), z0 - 1),
               glm::dvec3(s.edge_x(z0, x1), s.edge_y(z0, y0), z0 + 1), shift};
  };
  const glm::dvec2 shift_a(1.25, -0.6), shift_b(-0.5, 1.3);
  s.media = {box(5, 15, 3, 10, glm::dvec3(shift_a.x / ppx, -shift_a.y / ppy, 0)),
             box(10, 25, 8, 18, glm::dvec3(shift_b.x / ppx, -shift_b.y / ppy, 0)),
             box(28, 35, 2, 8, glm::dvec3(0, 0, -10))};
  Expected e = reference(s);
  ASSERT_FALSE(e.ambiguous);
  guiding::VolumeMotion vm(context(), s.W, s.H);
  std::vector<glm::vec4> out = run(s, &vm);
  EXPECT_EQ(compare(s, out, e), 0);

  // Independently of the reference: each landed point's motion is the disparity minus its medium's shift.
  auto in_box = [](int x, int y, int x0, int x1, int y0, int y1) {
    return x >= x0 && x < x1 && y >= y0 && y < y1;
  };
  int from_a = 0, from_b = 0, from_c = 0;
  for (int t = 0; t < s.W * s.H; ++t) {
    if (out[t].w == 0) continue;
    const int x = e.source[t] % s.W, y = e.source[t] / s.W;
    glm::dvec2 want(disparity, 0);
    if (in_box(x, y, 5, 15, 3, 10)) {
      want -= shift_a;
      ++from_a;
    } else if (in_box(x, y, 10, 25, 8, 18)) {
      want -= shift_b;
      ++from_b;
    } else if (in_box(x, y, 28, 35, 2, 8)) {
      ++from_c;
    }
    EXPECT_NEAR(out[t].x, want.x, kMotionTol);
    EXPECT_NEAR(out[t].y, want.y, kMotionTol);
  }
  EXPECT_GT(from_a, 40);
  EXPECT_GT(from_b, 80);
  EXPECT_EQ(from_c, 0);

  // A media buffer with count 0 moves nothing: the same as the static plane (on the same instance, so
  // nothing of the previous run may be left in its keys).
  s.media.clear();
  e = reference(s);
  EXPECT_EQ(compare(s, run(s, &vm, true), e), 0);
  EXPECT_EQ(context().validation_messages(), 0u);
}

TEST(VolumeMotion, TinyAndOddSizes) {
  // 1x1: the point straight ahead at distance 5, the camera moves so that it shifts by 0.2 pixel.
  Case one(1, 1);
  one.plane(5);
  one.cur.pos = glm::dvec3(0.2 / one.pixels_per_unit_x(5), 0, 0);
  std::vector<glm::vec4> out = run(one);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].w, 1.f);
  EXPECT_NEAR(out[0].x, 0.2, kMotionTol);
  EXPECT_NEAR(out[0].y, 0, kMotionTol);
  EXPECT_NEAR(out[0].z, glm::length(glm::dvec3(0, 0, 5) - one.cur.pos) - 5, kDeltaTol);
  one.depth[0] = 0;
  out = run(one);
  EXPECT_EQ(out[0], glm::vec4(surface_motion(0, 0), 0, 0));

  // Sizes that are no multiple of the 8x8 workgroup, a moving camera (turning too where the image is wide
  // enough to keep the points).
  for (glm::ivec2 size : {glm::ivec2(13, 9), glm::ivec2(1, 17), glm::ivec2(21, 1)}) {
    Case s(size.x, size.y);
    s.plane(4.3);
    s.cur.pos = glm::dvec3(0.3 / s.pixels_per_unit_x(4.3), 0.2 / s.pixels_per_unit_y(4.3), -0.23);
    if (size.x > 1 && size.y > 1) {
      glm::dmat3 r = glm::dmat3(glm::rotate(glm::dmat4(1), glm::radians(2.5), glm::dvec3(0, 1, 0)));
      s.cur.right = r * s.cur.right;
      s.cur.fwd = r * s.cur.fwd;
    }
    Expected e = reference(s);
    ASSERT_FALSE(e.ambiguous) << size.x << "x" << size.y;
    EXPECT_GT(e.landed, 0);
    EXPECT_EQ(compare(s, run(s), e), 0) << size.x << "x" << size.y;
  }
  EXPECT_EQ(context().validation_messages(), 0u);
}

}  // namespace
}  // namespace haze::test
