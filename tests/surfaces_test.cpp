// Surfaces: OBJ loading and its errors, bad-triangle handling, primitives, BVH invariants on the CPU, and
// the shaders' BVH traversal on lavapipe (validation on) against Embree's own intersector.
#include <gtest/gtest.h>
#include <stb/stb_image_write.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/packing.hpp>
#include <glm/gtx/component_wise.hpp>
#include <iostream>
#include <limits>
#include <memory>
#include <random>
#include <thread>

#include "gpu/gpu.hpp"
#include "shaders/glsl.hpp"
#include "surfaces/bvh.hpp"
#include "surfaces/embree_ref.hpp"
#include "surfaces/mesh.hpp"
#include "surfaces/scene_geometry.hpp"
#include "surfaces/texture.hpp"

namespace haze::surfaces {
namespace {

using glsl::GpuBvhNode;
using glsl::GpuRay;
using glsl::GpuRayHit;
using glsl::GpuTriangle;
constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// ---------------------------------------------------------------------------------------------------------
// Process-wide GPU state: one Context (which keeps the trace kernels' pipelines once created).

struct Shared {
  std::unique_ptr<gpu::Context> ctx;
};
Shared& shared() {
  static Shared s;
  return s;
}

std::filesystem::path temp_root() {
  return std::filesystem::temp_directory_path() / ("haze_surfaces_test_" + std::to_string(::getpid()));
}

class Environment : public ::testing::Environment {
 public:
  void TearDown() override {  // before main returns, while the Vulkan loader is surely alive
    shared().ctx.reset();
    std::error_code ec;
    std::filesystem::remove_all(temp_root(), ec);
  }
};
[[maybe_unused]] auto* const environment = ::testing::AddGlobalTestEnvironment(new Environment);

gpu::Context& ctx() {
  if (!shared().ctx) {
    gpu::ContextOptions o;
    o.validation = true;
    shared().ctx = std::make_unique<gpu::Context>(o);
  }
  return *shared().ctx;
}

std::string joined(const std::vector<std::string>& log) {
  std::string s;
  for (const auto& l : log) s += l + "\n";
  return s;
}

// Runs trace_rays.comp over `rays`; gpu_ms (when given) receives the dispatch's GPU time.
std::vector<GpuRayHit> trace(const Bvh& bvh, const std::vector<GpuRay>& rays, bool any_hit,
                             double* gpu_ms = nullptr) {
  gpu::Context& c = ctx();
  DeviceBvh d = upload(c, bvh);
  gpu::Buffer ray_buf(c, "test rays", "test", rays.size() * sizeof(GpuRay), "GpuRay");
  ray_buf.upload(rays);
  gpu::Buffer hit_buf(c, "test hits", "test", rays.size() * sizeof(GpuRayHit), "GpuRayHit");
  const gpu::Kernel k(c, trace_rays_decl(d, rays.size(), any_hit));
  gpu::Bindings b;
  d.bind(b);
  b.set("rays", ray_buf).set("hits", hit_buf);
  const uint32_t count = uint32_t(rays.size());
  gpu::Timer timer(c, 4);
  c.submit_and_wait([&](VkCommandBuffer cmd) {
    timer.reset(cmd);
    timer.begin(cmd, "trace");
    k.dispatch_1d(cmd, b, &count, count);
    timer.end(cmd);
  });
  if (gpu_ms) *gpu_ms = timer.read_ms().at(0).second;
  return hit_buf.download_vector<GpuRayHit>();
}

GpuRay make_ray(glm::vec3 o, glm::vec3 d, float tmin, float tmax) {
  return {glsl::vec4(o, tmin), glsl::vec4(d, tmax)};
}

std::string write_file(const std::string& name, const std::string& text) {
  std::filesystem::create_directories(temp_root());
  const std::string path = (temp_root() / name).string();
  std::ofstream(path) << text;
  return path;
}

// Error text of f(), "" when it does not throw.
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// ---------------------------------------------------------------------------------------------------------
// Meshes and OBJ files

// A unit square pyramid: a quad base (triangulated by the loader) and four triangles, with uvs and normals.
const char* kPyramidObj = R"(# test pyramid
o pyramid
v -0.5 0 -0.5
v 0.5 0 -0.5
v 0.5 0 0.5
v -0.5 0 0.5
v 0 0.8 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vt 0.5 0.5
vn 0 -1 0
vn 0 1 0
f 1/1/1 2/2/1 3/3/1 4/4/1
f 1/1/2 5/5/2 2/2/2
f 2/2/2 5/5/2 3/3/2
f 3/3/2 5/5/2 4/4/2
f 4/4/2 5/5/2 1/1/2
)";

TEST(Mesh, ObjLoadsTrianglesWithSharedVertices) {
  MeshStats stats;
  Mesh m = load_obj(write_file("pyramid.obj", kPyramidObj), &stats);
  EXPECT_EQ(m.triangles.size(), 6u);
  EXPECT_EQ(stats.triangles, 6u);
  EXPECT_EQ(stats.dropped(), 0u);
  // Corners share a vertex only when position, uv and normal all agree: 4 base + 4 side + apex.
  EXPECT_EQ(m.positions.size(), 9u);
  EXPECT_EQ(m.normals.size(), m.positions.size());
  EXPECT_EQ(m.uvs.size(), m.positions.size());
  EXPECT_NEAR(surface_area(m), 1.0 + 4 * 0.5 * 1.0 * std::sqrt(0.64 + 0.25), 1e-5);

  // Without uvs on every corner the mesh has none; positions then merge across faces.
  Mesh bare =
      load_obj(write_file("bare.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4/1 3\nvt 0 0\n"));
  EXPECT_TRUE(bare.uvs.empty());
  EXPECT_TRUE(bare.normals.empty());
  EXPECT_EQ(bare.positions.size(), 4u);
  EXPECT_EQ(bare.triangles.size(), 2u);
}

TEST(Mesh, ObjErrorsNameTheFileAndSayWhatToDo) {
  const std::string missing = (temp_root() / "nope.obj").string();
  std::string e = error_of([&] { load_obj(missing); });
  EXPECT_NE(e.find(missing), std::string::npos) << e;
  EXPECT_NE(e.find("no such file"), std::string::npos) << e;

  struct Case {
    const char* name;
    const char* text;
    const char* says;
  };
  const Case cases[] = {
      {"zero_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "malformed OBJ"},
      {"out_of_range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "refers to vertex 9 but the file has 3"},
      {"two_corners.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\n", "fewer than 3 vertices"},
      {"no_faces.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangles"},
      {"garbage.obj", "\x01\x02 this is not an OBJ file\n", "no triangles"},
      {"all_degenerate.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n", "no valid triangles"},
      // tinyobjloader reads these as 0 or skips them without a word.
      {"banana.obj", "v 0 0 0\nv 1 0 banana\nv 0 1 0\nf 1 2 3\n",
       ":2: malformed OBJ: 'banana' in a 'v' line is not a number"},
      {"banana_uv.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 x\nf 1 2 3\n",
       ":4: malformed OBJ: 'x' in a 'vt' line"},
      {"bare_f.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf\nf 1 2 3\n",
       ":4: malformed OBJ: a face with fewer than 3 vertices (0"},
  };
  for (const Case& c : cases) {
    const std::string path = write_file(c.name, c.text);
    e = error_of([&] { load_obj(path); });
    EXPECT_NE(e.find(path), std::string::npos) << c.name << ": " << e;
    EXPECT_NE(e.find(c.says), std::string::npos) << c.name << ": " << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << c.name << ": one line: " << e;
  }
}

TEST(Mesh, NonFiniteAndZeroAreaTrianglesAreDroppedAndCounted) {
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {kNaN, 0, 0}, {0, kInf, 0}, {2, 0, 0}, {1e-3f, 1e-3f, 0}};
  m.triangles = {{0, 1, 2},   // good
                 {0, 1, 3},   // NaN
                 {4, 1, 2},   // Inf
                 {0, 0, 1},   // repeated vertex
                 {0, 1, 5},   // collinear
                 {0, 1, 6}};  // a small but real sliver stays
  MeshStats s = drop_bad_triangles(m);
  EXPECT_EQ(s.triangles, 2u);
  EXPECT_EQ(s.dropped_nonfinite, 2u);
  EXPECT_EQ(s.dropped_degenerate, 2u);
  ASSERT_EQ(m.triangles.size(), 2u);
  EXPECT_EQ(m.triangles[0], glm::uvec3(0, 1, 2));
  EXPECT_EQ(m.triangles[1], glm::uvec3(0, 1, 6));

  Mesh bad;
  bad.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  bad.triangles = {{0, 1, 3}};
  EXPECT_NE(error_of([&] { drop_bad_triangles(bad); }).find("refers to vertex 3 of 3"), std::string::npos);

  // The same through an OBJ file: 1e39 overflows float to Inf, nan and inf are not finite (tinyobjloader
  // would read both as 0), a repeated corner has zero area.
  MeshStats os;
  Mesh o = load_obj(write_file("bad_tris.obj",
                               "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e39 0 0\nv 0.5 0.5 inf\nv nan 0 1 # comment\n"
                               "f 1 2 3\nf 1 2 4\nf 1 1 2\nf 3 2 1\nf 1 2 5\nf 6 1 2\n"),
                    &os);
  EXPECT_EQ(o.triangles.size(), 2u);
  EXPECT_EQ(os.triangles, 2u);
  EXPECT_EQ(os.dropped_nonfinite, 3u);
  EXPECT_EQ(os.dropped_degenerate, 1u);
  // A non-finite uv drops its triangles too.
  MeshStats us;
  load_obj(write_file("bad_uv.obj",
                      "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 inf\n"
                      "f 1/1 2/2 3/1\nf 2/2 4/3 3/1\n"),
           &us);
  EXPECT_EQ(us.triangles, 1u);
  EXPECT_EQ(us.dropped_nonfinite, 1u);
}

// ---------------------------------------------------------------------------------------------------------
// Textures

TEST(Texture, EightBitIsSrgbAndHdrIsLinear) {
  std::filesystem::create_directories(temp_root());
  const std::string png = (temp_root() / "t.png").string();
  const unsigned char px[2 * 1 * 3] = {0, 128, 255, 10, 200, 40};
  ASSERT_TRUE(stbi_write_png(png.c_str(), 2, 1, 3, px, 6));
  Texture t = load_texture(png);
  ASSERT_EQ(t.width, 2u);
  ASSERT_EQ(t.height, 1u);
  auto srgb = [](double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); };
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(t.at(i / 3, 0)[i % 3], srgb(px[i] / 255.0), 1e-6) << i;

  // RGBE holds 0.75, 0.25 and 0.125 exactly (one shared exponent, 8-bit mantissas).
  const std::string hdr = (temp_root() / "t.hdr").string();
  const float linear[3] = {0.75f, 0.25f, 0.125f};
  ASSERT_TRUE(stbi_write_hdr(hdr.c_str(), 1, 1, 3, linear));
  Texture h = load_texture(hdr);
  EXPECT_EQ(h.at(0, 0), glm::vec3(0.75f, 0.25f, 0.125f));

  // Packed for the shaders: 16-bit unorm, the tolerance the G-buffer test allows for.
  std::vector<glm::uvec2> packed;
  pack_texels(h, packed);
  ASSERT_EQ(packed.size(), 1u);
  // round(v * 65535): r 0xbfff, g 0x4000 (high half), b 0x2000.
  EXPECT_EQ(packed[0], glm::uvec2(0x4000bfffu, 0x2000u));
}

TEST(Texture, BadFilesAreNamed) {
  std::filesystem::create_directories(temp_root());
  const std::string missing = (temp_root() / "none.png").string();
  std::string e = error_of([&] { load_texture(missing); });
  EXPECT_NE(e.find(missing), std::string::npos) << e;
  EXPECT_NE(e.find("no such file"), std::string::npos) << e;

  const std::string garbage = write_file("garbage.png", "definitely not an image");
  e = error_of([&] { load_texture(garbage); });
  EXPECT_NE(e.find(garbage), std::string::npos) << e;
  EXPECT_NE(e.find("cannot decode"), std::string::npos) << e;

  // A PNG cut short after its header.
  const std::string whole = (temp_root() / "whole.png").string();
  std::vector<unsigned char> px(64 * 64 * 3, 77);
  ASSERT_TRUE(stbi_write_png(whole.c_str(), 64, 64, 3, px.data(), 64 * 3));
  std::string bytes;
  {
    std::ifstream in(whole, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  const std::string cut = write_file("cut.png", bytes.substr(0, 60));
  e = error_of([&] { load_texture(cut); });
  EXPECT_NE(e.find(cut), std::string::npos) << e;

  // An unknown critical chunk after IHDR: stb's reason holds the chunk type's raw bytes; the message shows
  // them escaped.
  std::string chunk = std::string("\0\0\0\0", 4) +
                      "\x01\x9b"
                      "A\x10";
  chunk += std::string(4, '\0');  // CRC, not checked by stb
  const std::string odd = write_file("odd_chunk.png", bytes.substr(0, 33) + chunk + bytes.substr(33));
  e = error_of([&] { load_texture(odd); });
  EXPECT_NE(e.find("\\x01\\x9bA\\x10"), std::string::npos) << e;
  for (char c : e) EXPECT_TRUE(c >= 32 && c < 127) << "unprintable byte " << int(c) << " in: " << e;

  // An albedo over 1 is refused (the texel is named).
  const std::string bright = (temp_root() / "bright.hdr").string();
  const float hot[6] = {0.5f, 0.5f, 0.5f, 2.0f, 0.5f, 0.5f};
  ASSERT_TRUE(stbi_write_hdr(bright.c_str(), 2, 1, 3, hot));
  e = error_of([&] { load_texture(bright); });
  EXPECT_NE(e.find("texel (1, 0)"), std::string::npos) << e;
  EXPECT_NE(e.find("[0, 1]"), std::string::npos) << e;
  for (const std::string& m : {missing, garbage, cut, bright})
    EXPECT_EQ(error_of([&] { load_texture(m); }).find('\n'), std::string::npos) << m;
}

// ---------------------------------------------------------------------------------------------------------
// Primitives

// Every triangle's geometric normal points away from `inside` (closed, convex-around-a-point meshes).
void expect_outward(const Mesh& m, glm::vec3 inside, const char* what) {
  size_t wrong = 0;
  for (glm::uvec3 t : m.triangles) {
    glm::vec3 a = m.positions[t.x], b = m.positions[t.y], c = m.positions[t.z];
    glm::vec3 n = glm::cross(b - a, c - a);
    if (glm::dot(n, (a + b + c) / 3.0f - inside) <= 0) ++wrong;
  }
  EXPECT_EQ(wrong, 0u) << what;
}

// Shading normals agree with the geometric ones (flat primitives) or lean the same way (sphere).
void expect_normals_match(const Mesh& m, float min_cos, const char* what) {
  ASSERT_EQ(m.normals.size(), m.positions.size()) << what;
  ASSERT_EQ(m.uvs.size(), m.positions.size()) << what;
  float worst = 1;
  for (glm::uvec3 t : m.triangles) {
    glm::vec3 a = m.positions[t.x], b = m.positions[t.y], c = m.positions[t.z];
    glm::vec3 n = glm::normalize(glm::cross(b - a, c - a));
    for (int k = 0; k < 3; ++k) worst = std::min(worst, glm::dot(n, m.normals[t[k]]));
  }
  EXPECT_GE(worst, min_cos) << what;
}

void expect_no_bad_triangles(Mesh m, const char* what) {
  EXPECT_EQ(drop_bad_triangles(m).dropped(), 0u) << what;
}

TEST(Primitives, ShapesAreaAndOrientation) {
  Mesh p = plane({2, 3});
  EXPECT_EQ(p.triangles.size(), 2u);
  EXPECT_NEAR(surface_area(p), 6.0, 1e-6);
  expect_outward(p, {0, 0, -1}, "plane faces +z");
  expect_normals_match(p, 0.9999f, "plane");

  Mesh b = box({1, 2, 3});
  EXPECT_EQ(b.triangles.size(), 12u);
  EXPECT_NEAR(surface_area(b), 2 * (2 + 6 + 3), 1e-5);
  expect_outward(b, glm::vec3(0), "box");
  expect_normals_match(b, 0.9999f, "box");

  Mesh s = sphere(2, 64);
  EXPECT_EQ(s.triangles.size(), 64u * 2 * (32 - 1));
  EXPECT_NEAR(surface_area(s), 4 * M_PI * 4, 4 * M_PI * 4 * 0.01);
  expect_outward(s, glm::vec3(0), "sphere");
  expect_normals_match(s, 0.95f, "sphere");
  for (glm::vec3 v : s.positions) EXPECT_NEAR(glm::length(v), 2.0f, 1e-5f);
  expect_no_bad_triangles(sphere(1, 3), "coarsest sphere");

  // 4 frame bars and 6 slats, each a box; everything inside width x height x frame depth (rotated slats
  // reach out to their chord).
  Mesh w = window(2, 1.5, 0.1f, 6, 0.02f, 30);
  EXPECT_EQ(w.triangles.size(), 12u * (4 + 6));
  const float chord = (1.5f - 0.2f) / 6;
  for (glm::vec3 v : w.positions) {
    EXPECT_LE(std::abs(v.x), 1.0f + 1e-5f);
    EXPECT_LE(std::abs(v.y), 0.75f + 1e-5f);
    EXPECT_LE(std::abs(v.z), 0.5f * chord + 1e-5f);
  }
  expect_normals_match(w, 0.9999f, "window");
  expect_no_bad_triangles(w, "window");
  // Closed blinds cover the opening: the slats' projected area equals the opening's.
  Mesh closed = window(2, 1.5, 0.1f, 6, 0.02f, 90);
  double facing = 0;
  for (glm::uvec3 t : closed.triangles) {
    glm::vec3 a = closed.positions[t.x], bb = closed.positions[t.y], c = closed.positions[t.z];
    glm::vec3 n = glm::cross(bb - a, c - a);
    if (n.z > 0) facing += 0.5 * n.z;
  }
  const double frame_front = 2 * 1.5 - 1.8 * 1.3;
  EXPECT_NEAR(facing, frame_front + 1.8 * 1.3, 1e-4);
  EXPECT_EQ(window(1, 1, 0.1f, 0, 0, 0).triangles.size(), 48u);   // frame only
  EXPECT_EQ(window(1, 1, 0, 3, 0.01f, 0).triangles.size(), 36u);  // slats only

  Mesh panel = perforated_panel(3, 2, 6, 4, 0.2f);
  EXPECT_NEAR(surface_area(panel), 6.0 - 24 * 0.04, 1e-4);
  EXPECT_EQ(panel.triangles.size(), 2u * 8 * 24);
  expect_outward(panel, {0, 0, -1}, "panel faces +z");
  expect_normals_match(panel, 0.9999f, "panel");
  expect_no_bad_triangles(panel, "panel");
}

TEST(Primitives, ParametersAreChecked) {
  struct Case {
    std::function<void()> make;
    const char* says;
  };
  const Case cases[] = {
      {[] {
         plane({0, 1});
       },
       "plane: size"},
      {[] {
         plane({kNaN, 1});
       },
       "plane: size"},
      {[] {
         box({1, -1, 1});
       },
       "box: size"},
      {[] {
         box({1, kInf, 1});
       },
       "box: size"},
      {[] { sphere(0, 16); }, "sphere: radius"},
      {[] { sphere(1, 2); }, "sphere: segments"},
      {[] { window(0, 1, 0.1f, 3, 0.01f, 0); }, "window: width"},
      {[] { window(1, 1, 0.5f, 3, 0.01f, 0); }, "window: frame"},
      {[] { window(1, 1, -0.1f, 3, 0.01f, 0); }, "window: frame"},
      {[] { window(1, 1, 0.1f, 4, 0.3f, 0); }, "window: slat_thickness"},
      {[] { window(1, 1, 0.1f, 4, 0.0f, 0); }, "window: slat_thickness"},
      {[] { window(1, 1, 0.1f, 4, 0.01f, 95); }, "window: slat_angle_deg"},
      {[] { window(1, 1, 0, 0, 0.01f, 0); }, "window: no geometry"},
      {[] { perforated_panel(1, 1, 0, 2, 0.1f); }, "perforated_panel: holes_x"},
      {[] { perforated_panel(1, 1, 4, 4, 0.25f); }, "perforated_panel: hole_size"},
      {[] { perforated_panel(1, -1, 4, 4, 0.1f); }, "perforated_panel: width"},
  };
  for (const Case& c : cases) {
    std::string e = error_of(c.make);
    EXPECT_EQ(e.rfind(c.says, 0), 0u) << "expected '" << c.says << "...', got '" << e << "'";
  }
}

// ---------------------------------------------------------------------------------------------------------
// World triangles and the BVH

// The scene the GPU test traces: a sphere, a window with slats, a box, the sphere again under rotation and
// non-uniform scale, a perforated panel and an OBJ file, in world space.
struct TestScene {
  std::vector<Mesh> meshes;
  std::vector<Instance> instances;
  std::vector<GpuTriangle> triangles;
  glm::vec3 lo{kInf}, hi{-kInf};
};

TestScene test_scene() {
  TestScene s;
  s.meshes.push_back(sphere(1, 48));
  s.meshes.push_back(window(2, 1.5f, 0.1f, 8, 0.02f, 30));
  s.meshes.push_back(box({1, 0.5f, 0.8f}));
  s.meshes.push_back(perforated_panel(3, 2, 6, 4, 0.2f));
  s.meshes.push_back(load_obj(write_file("scene_pyramid.obj", kPyramidObj)));
  auto at = [](glm::vec3 t) { return glm::translate(glm::mat4(1), t); };
  glm::mat4 squashed =
      glm::rotate(at({0, 1.8f, -1}), glm::radians(35.0f), glm::normalize(glm::vec3(1, 1, 0)));
  squashed = glm::scale(squashed, {0.5f, 1.2f, 0.8f});
  s.instances = {
      {0, at({-2, 0, 0})},       {1, glm::rotate(at({1.5f, 0, 0}), glm::radians(20.0f), glm::vec3(0, 1, 0))},
      {2, at({0, -1.5f, 0.5f})}, {0, squashed},
      {3, at({0, 0, -2.5f})},    {4, glm::scale(at({0.3f, 0.2f, 1.5f}), glm::vec3(1.5f))}};
  s.triangles = world_triangles(s.meshes, s.instances);
  for (const GpuTriangle& t : s.triangles)
    for (glsl::vec4 v : {t.v0, t.v1, t.v2}) {
      s.lo = glm::min(s.lo, glm::vec3(v));
      s.hi = glm::max(s.hi, glm::vec3(v));
    }
  return s;
}

TEST(Bvh, WorldTrianglesCarryIdsAndTransforms) {
  std::vector<Mesh> meshes = {box({1, 1, 1}), plane({1, 1})};
  glm::mat4 m = glm::scale(glm::translate(glm::mat4(1), {1, 2, 3}), {2, 2, 2});
  glm::mat4 mirror = glm::scale(glm::mat4(1), {-1, 1, 1});
  std::vector<Instance> inst = {{1, glm::mat4(1)}, {0, m}, {1, mirror}};
  std::vector<GpuTriangle> w = world_triangles(meshes, inst);
  ASSERT_EQ(w.size(), 2u + 12u + 2u);
  for (uint32_t i = 0; i < w.size(); ++i) EXPECT_EQ(input_index(w[i]), i);
  EXPECT_EQ(instance_id(w[0]), 0u);
  EXPECT_EQ(instance_id(w[2]), 1u);
  EXPECT_EQ(primitive_id(w[2 + 11]), 11u);
  glm::vec3 p = meshes[0].positions[meshes[0].triangles[5].x];
  EXPECT_EQ(glm::vec3(w[2 + 5].v0), glm::vec3(m * glm::vec4(p, 1)));
  // The mirrored plane still faces +z.
  for (int i : {14, 15})
    EXPECT_GT(glm::cross(glm::vec3(w[i].v1 - w[i].v0), glm::vec3(w[i].v2 - w[i].v0)).z, 0);

  EXPECT_NE(error_of([&] {
              world_triangles(meshes, std::vector<Instance>{{2, glm::mat4(1)}});
            }).find("instance 0: mesh 2"),
            std::string::npos);
  const glm::mat4 flat = glm::scale(glm::mat4(1), {1, 0, 1});
  EXPECT_NE(error_of([&] {
              world_triangles(meshes, std::vector<Instance>{{0, flat}});
            }).find("singular"),
            std::string::npos);
  EXPECT_NE(error_of([&] {
              world_triangles(meshes, std::vector<Instance>{{0, glm::mat4(0)}});
            }).find("affine"),
            std::string::npos);
  glm::mat4 nan(1);
  nan[3][0] = kNaN;
  EXPECT_NE(error_of([&] {
              world_triangles(meshes, std::vector<Instance>{{0, nan}});
            }).find("NaN"),
            std::string::npos);
}

// Structural checks: every triangle in exactly one leaf, leaves tile the triangle array in order, child
// boxes inside their parent's, triangles inside their leaf's box, depth within the shader's stack.
void check_invariants(const Bvh& bvh, std::span<const GpuTriangle> input, uint32_t max_leaf) {
  ASSERT_FALSE(bvh.nodes.empty());
  ASSERT_EQ(bvh.triangles.size(), input.size());
  std::vector<int> seen(input.size(), 0);
  for (const GpuTriangle& t : bvh.triangles) {
    ASSERT_LT(input_index(t), input.size());
    ++seen[input_index(t)];
    const GpuTriangle& o = input[input_index(t)];
    EXPECT_TRUE(o.v0 == t.v0 && o.v1 == t.v1 && o.v2 == t.v2);
  }
  for (size_t i = 0; i < seen.size(); ++i) EXPECT_EQ(seen[i], 1) << "triangle " << i;

  auto lo = [](const GpuBvhNode& n) { return glm::vec3(n.bmin_left_or_first); };
  auto hi = [](const GpuBvhNode& n) { return glm::vec3(n.bmax_count); };
  auto inside = [](glm::vec3 a_lo, glm::vec3 a_hi, glm::vec3 b_lo, glm::vec3 b_hi) {
    return glm::all(glm::greaterThanEqual(a_lo, b_lo)) && glm::all(glm::lessThanEqual(a_hi, b_hi));
  };
  std::vector<int> referenced(bvh.nodes.size(), 0);
  uint32_t next_triangle = 0, leaves = 0, depth = 0;
  // Depth-first in the flattener's order, so leaves must cover the triangle array front to back.
  std::vector<std::pair<uint32_t, uint32_t>> stack = {{0, 1}};
  while (!stack.empty()) {
    auto [i, d] = stack.back();
    stack.pop_back();
    ASSERT_LT(i, bvh.nodes.size());
    ASSERT_EQ(referenced[i]++, 0) << "node " << i << " reached twice";
    depth = std::max(depth, d);
    const GpuBvhNode& n = bvh.nodes[i];
    const uint32_t first = glm::floatBitsToUint(n.bmin_left_or_first.w);
    const uint32_t count = glm::floatBitsToUint(n.bmax_count.w);
    if (count == glsl::BVH_INTERNAL) {
      ASSERT_GT(first, i);
      ASSERT_LT(first + 1, bvh.nodes.size());
      for (uint32_t c : {first, first + 1})
        EXPECT_TRUE(inside(lo(bvh.nodes[c]), hi(bvh.nodes[c]), lo(n), hi(n))) << "child " << c << " of " << i;
      stack.push_back({first + 1, d + 1});
      stack.push_back({first, d + 1});
      continue;
    }
    ++leaves;
    EXPECT_EQ(first, next_triangle);
    EXPECT_GE(count, input.empty() ? 0u : 1u);
    EXPECT_LE(count, max_leaf);
    next_triangle += count;
    for (uint32_t k = first; k < first + count && k < bvh.triangles.size(); ++k) {
      const GpuTriangle& t = bvh.triangles[k];
      for (glsl::vec4 v : {t.v0, t.v1, t.v2})
        EXPECT_TRUE(inside(glm::vec3(v), glm::vec3(v), lo(n), hi(n))) << "triangle " << k << " leaf " << i;
    }
  }
  EXPECT_EQ(next_triangle, input.size());
  for (size_t i = 0; i < referenced.size(); ++i) EXPECT_EQ(referenced[i], 1) << "node " << i;
  EXPECT_EQ(leaves, bvh.leaves);
  EXPECT_EQ(depth, bvh.depth);
  EXPECT_LE(bvh.depth, glsl::BVH_STACK_SIZE + 1);
  if (!input.empty()) {
    EXPECT_EQ(bvh.nodes.size(), 2 * size_t(leaves) - 1);
  }
}

TEST(Bvh, InvariantsHold) {
  TestScene s = test_scene();
  for (uint32_t leaf : {1u, 4u, 16u}) {
    BvhOptions o;
    o.max_leaf_size = leaf;
    Bvh bvh = build_bvh(s.triangles, o);
    SCOPED_TRACE("max_leaf_size " + std::to_string(leaf));
    check_invariants(bvh, s.triangles, leaf);
    std::cout << "max_leaf_size " << leaf << ": " << s.triangles.size() << " triangles, " << bvh.nodes.size()
              << " nodes, " << bvh.leaves << " leaves, depth " << bvh.depth << "\n";
  }
  // One triangle: the root is a leaf. None: one empty leaf.
  std::span<const GpuTriangle> one(s.triangles.data(), 1);
  Bvh single = build_bvh(one);
  check_invariants(single, one, 4);
  EXPECT_EQ(single.nodes.size(), 1u);
  Bvh empty = build_bvh({});
  check_invariants(empty, {}, 0);
  // Many identical triangles (no useful split) still make a valid, shallow tree.
  std::vector<GpuTriangle> same(5000, s.triangles[0]);
  for (uint32_t i = 0; i < same.size(); ++i) same[i].v2.w = glm::uintBitsToFloat(i);
  Bvh stacked = build_bvh(same);
  check_invariants(stacked, same, 4);

  BvhOptions bad;
  bad.max_leaf_size = 0;
  EXPECT_NE(error_of([&] { build_bvh(s.triangles, bad); }).find("max_leaf_size"), std::string::npos);
}

// ---------------------------------------------------------------------------------------------------------
// GPU traversal against Embree

class BvhGpu : public ::testing::Test {
 protected:
  void TearDown() override { EXPECT_EQ(ctx().validation_messages(), 0u) << joined(ctx().validation_log()); }
};

// Random rays over the scene: a third aimed at interior points of random triangles, some exactly at
// mesh vertices and edge midpoints (watertightness), some axis-aligned (zero direction components), the
// rest uniform; finite and infinite tmax, zero and positive tmin.
std::vector<GpuRay> random_rays(const TestScene& s, size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u01(0, 1);
  const glm::vec3 lo = s.lo - 1.0f, hi = s.hi + 1.0f;
  std::uniform_int_distribution<size_t> pick(0, s.triangles.size() - 1);
  std::vector<GpuRay> rays;
  rays.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    glm::vec3 o = lo + (hi - lo) * glm::vec3(u01(rng), u01(rng), u01(rng));
    glm::vec3 d;
    const float kind = u01(rng);
    const GpuTriangle& t = s.triangles[pick(rng)];
    const glm::vec3 a(t.v0), b(t.v1), c(t.v2);
    if (kind < 0.33f) {
      float x = u01(rng), y = u01(rng);
      if (x + y > 1) x = 1 - x, y = 1 - y;
      d = a + x * (b - a) + y * (c - a) - o;
    } else if (kind < 0.40f) {
      d = a - o;  // a vertex shared by several triangles
    } else if (kind < 0.47f) {
      d = 0.5f * (a + b) - o;  // an edge, shared in closed meshes
    } else if (kind < 0.52f) {
      d = glm::vec3(0);
      d[int(u01(rng) * 3) % 3] = u01(rng) < 0.5f ? -1.0f : 1.0f;
    } else {
      float z = 2 * u01(rng) - 1, phi = 2 * float(M_PI) * u01(rng), r = std::sqrt(std::max(0.0f, 1 - z * z));
      d = {r * std::cos(phi), r * std::sin(phi), z};
    }
    if (glm::length(d) < 1e-6f) d = glm::vec3(0, 0, 1);
    if (u01(rng) < 0.5f) d = glm::normalize(d);  // unnormalized directions too
    const float tmin = u01(rng) < 0.8f ? 0.0f : 0.3f * u01(rng);
    const float tmax = u01(rng) < 0.7f ? kInf : tmin + 8 * u01(rng);
    rays.push_back(make_ray(o, d, tmin, tmax));
  }
  return rays;
}

// Distance (double precision) from a ray's line to the nearest edge of a triangle.
double edge_distance(const GpuTriangle& t, const GpuRay& ray) {
  const glm::dvec3 o(ray.origin_tmin), d = glm::normalize(glm::dvec3(ray.direction_tmax));
  const glm::dvec3 v[3] = {glm::dvec3(t.v0), glm::dvec3(t.v1), glm::dvec3(t.v2)};
  double best = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 3; ++k) {
    const glm::dvec3 p = v[k], e = v[(k + 1) % 3] - p, w = p - o;
    // Closest point of the segment p + u e (u in [0, 1]) to the line o + s d: the distance is convex in u,
    // so the unconstrained minimiser, clamped, is the answer.
    const double b = glm::dot(d, e), c = glm::dot(e, e), denom = c - b * b;
    const double u =
        denom > 1e-300 ? std::clamp((b * glm::dot(d, w) - glm::dot(e, w)) / denom, 0.0, 1.0) : 0.0;
    const glm::dvec3 q = p + u * e;
    best = std::min(best, glm::length((q - o) - glm::dot(q - o, d) * d));
  }
  return best;
}

TEST_F(BvhGpu, TraversalMatchesEmbree) {
  TestScene s = test_scene();
  Bvh bvh = build_bvh(s.triangles);
  EmbreeScene ref(s.triangles);
  const size_t n = 131072;
  std::vector<GpuRay> rays = random_rays(s, n, 12345);

  // The first dispatch of each pipeline pays its LLVM compile: time the second.
  trace(bvh, rays, false);
  trace(bvh, rays, true);
  double gpu_ms = 0, gpu_occ_ms = 0;
  std::vector<GpuRayHit> hits = trace(bvh, rays, false, &gpu_ms);
  std::vector<GpuRayHit> occ = trace(bvh, rays, true, &gpu_occ_ms);
  ASSERT_EQ(hits.size(), n);

  std::vector<RefHit> want(n);
  auto t0 = std::chrono::steady_clock::now();
  for (size_t i = 0; i < n; ++i)
    want[i] = ref.intersect(glm::vec3(rays[i].origin_tmin), glm::vec3(rays[i].direction_tmax),
                            rays[i].origin_tmin.w, rays[i].direction_tmax.w);
  const double embree_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();

  // Where the two disagree, the ray must pass within kGraze of an edge of the triangle one side hit
  // nearer: there float rounding decides (rays aimed at silhouette vertices and edges graze on purpose).
  const double kGraze = 1e-7 * glm::length(s.hi - s.lo);
  double worst_graze = 0;
  auto ambiguous = [&](uint32_t triangle, size_t i) {
    const double dist = edge_distance(s.triangles[triangle], rays[i]);
    if (dist <= kGraze) worst_graze = std::max(worst_graze, dist);
    return dist <= kGraze;
  };
  size_t hit_count = 0, shared_edge = 0, grazing = 0, wrong = 0, wrong_t = 0, wrong_uv = 0, wrong_normal = 0,
         wrong_ids = 0, wrong_occluded = 0, inconsistent = 0;
  double worst_rel = 0, worst_uv = 0;
  auto report = [&](size_t i, const char* what) {
    if (wrong++ < 10)
      ADD_FAILURE() << "ray " << i << " " << what << ": gpu " << (hits[i].t_uv.w == 1 ? "hit" : "miss")
                    << " t " << hits[i].t_uv.x << " triangle " << int(hits[i].ids.w) << ", embree "
                    << (want[i].hit() ? "hit" : "miss") << " t " << want[i].t << " triangle "
                    << int(want[i].triangle);
  };
  for (size_t i = 0; i < n; ++i) {
    const GpuRayHit& g = hits[i];
    const RefHit& r = want[i];
    const bool g_hit = g.t_uv.w == 1.0f;
    const float tmax = rays[i].direction_tmax.w;
    bool excused = false;
    // The GPU's two queries run the same triangle test: occluded exactly when the closest hit exists.
    if ((occ[i].t_uv.w == 1.0f) != g_hit) ++inconsistent;
    if (g_hit != r.hit()) {
      excused = ambiguous(g_hit ? g.ids.w : r.triangle, i);
      if (excused)
        ++grazing;
      else
        report(i, "hit/miss");
    } else if (!g_hit) {
      if (g.ids.x != glsl::BVH_NONE || g.t_uv.x != tmax) report(i, "a miss reports BVH_NONE and tmax");
    } else {
      ++hit_count;
      const float tol = 1e-4f * r.t + 1e-6f;  // relative, plus float resolution for hits next to the origin
      const float dt = std::abs(g.t_uv.x - r.t);
      const GpuTriangle& leaf_tri = bvh.triangles[g.ids.x];
      if (g.ids.y != instance_id(leaf_tri) || g.ids.z != primitive_id(leaf_tri) ||
          g.ids.w != input_index(leaf_tri))
        ++wrong_ids;
      if (g.ids.w != r.triangle) {
        if (dt <= tol) {
          ++shared_edge;  // both found the same point: an edge or vertex the two triangles share
        } else {
          excused = ambiguous(g.t_uv.x < r.t ? g.ids.w : r.triangle, i);
          if (excused)
            ++grazing;
          else
            report(i, "triangle");
        }
      } else {
        const float cos = std::abs(glm::dot(r.normal, glm::normalize(glm::vec3(rays[i].direction_tmax))));
        if (cos > 0.1f && r.t > 0.1f) worst_rel = std::max(worst_rel, double(dt / r.t));
        // t is ill-conditioned where the ray grazes the plane: there the tolerance grows with 1 / cos.
        if (dt > tol * std::max(1.0f, 0.01f / cos)) ++wrong_t;
        if (g.ids.y != r.instance || g.ids.z != r.primitive) ++wrong_ids;
        // Barycentrics too agree up to a 1 / cos factor.
        const float duv = glm::compMax(glm::abs(glm::vec2(g.t_uv.y, g.t_uv.z) - r.uv));
        worst_uv = std::max(worst_uv, double(duv * cos));
        if (duv * cos > 1e-4f) ++wrong_uv;
        if (glm::dot(glm::vec3(g.normal), r.normal) < 0.9999f) ++wrong_normal;
      }
    }
    // Embree's occlusion query against the GPU's, with the same excuse.
    const bool r_occ = ref.occluded(glm::vec3(rays[i].origin_tmin), glm::vec3(rays[i].direction_tmax),
                                    rays[i].origin_tmin.w, tmax);
    if ((occ[i].t_uv.w == 1.0f) != r_occ && !excused && !(g_hit && ambiguous(g.ids.w, i))) ++wrong_occluded;
  }
  std::cout << n << " rays, " << hit_count << " hits; " << shared_edge
            << " different triangles at the same t (shared edges), " << grazing
            << " grazing an edge (at most " << worst_graze << " away)"
            << "; worst relative t error (cos > 0.1, t > 0.1) " << worst_rel << ", worst uv error x cos "
            << worst_uv << "\n";
  EXPECT_EQ(wrong, 0u);
  EXPECT_EQ(wrong_t, 0u);
  EXPECT_EQ(wrong_ids, 0u);
  EXPECT_EQ(wrong_uv, 0u);
  EXPECT_EQ(wrong_normal, 0u);
  EXPECT_EQ(wrong_occluded, 0u);
  EXPECT_EQ(inconsistent, 0u);
  EXPECT_GT(hit_count, n / 3);  // the rays really exercise the geometry
  EXPECT_LT(grazing, n / 200);  // excuses stay rare
  EXPECT_LT(shared_edge, n / 20);

  // Throughput on this machine: lavapipe (all its threads) against Embree single-ray queries on one
  // thread and on every hardware thread.
  const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  t0 = std::chrono::steady_clock::now();
  {
    std::vector<std::thread> pool;
    for (unsigned k = 0; k < threads; ++k)
      pool.emplace_back([&, k] {
        for (size_t i = k; i < n; i += threads)
          want[i] = ref.intersect(glm::vec3(rays[i].origin_tmin), glm::vec3(rays[i].direction_tmax),
                                  rays[i].origin_tmin.w, rays[i].direction_tmax.w);
      });
    for (auto& t : pool) t.join();
  }
  const double embree_mt_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  auto mrays = [&](double ms) { return n / (ms * 1e3); };
  std::cout << "closest hit: GPU " << mrays(gpu_ms) << " Mrays/s (" << gpu_ms << " ms), occlusion "
            << mrays(gpu_occ_ms) << " Mrays/s; Embree 1 thread " << mrays(embree_ms) << " Mrays/s, "
            << threads << " threads " << mrays(embree_mt_ms) << " Mrays/s; GPU / Embree(" << threads
            << " threads) = " << embree_mt_ms / gpu_ms << "\n";
}

TEST_F(BvhGpu, WatertightAcrossSharedEdgesAndVertices) {
  // Rays onto every vertex and edge midpoint of a perforated panel (straight down) and of a finely
  // tessellated sphere (slanted, only where the surface faces the origin; at the silhouette a ray may
  // graze past legitimately): none may slip through between triangles.
  std::vector<Mesh> meshes = {perforated_panel(3, 2, 6, 4, 0.2f), sphere(1, 96)};
  std::vector<Instance> inst = {{0, glm::mat4(1)}, {1, glm::translate(glm::mat4(1), {0, 0, -4})}};
  std::vector<GpuTriangle> tris = world_triangles(meshes, inst);
  Bvh bvh = build_bvh(tris);
  const glm::vec3 o(0.1f, -0.2f, 0), centre(0, 0, -4);
  std::vector<GpuRay> rays;
  for (const GpuTriangle& t : tris) {
    const glm::vec3 a(t.v0), b(t.v1), c(t.v2);
    for (glm::vec3 p : {a, b, c, 0.5f * (a + b), 0.5f * (b + c), 0.5f * (c + a)}) {
      if (instance_id(t) == 0)  // exact even at the panel's and holes' borders
        rays.push_back(make_ray(p + glm::vec3(0, 0, 3), {0, 0, -1}, 0, kInf));
      else if (glm::dot(glm::normalize(p - centre), glm::normalize(o - p)) > 0.1f)
        rays.push_back(make_ray(o, p - o, 0, kInf));
    }
  }
  std::vector<GpuRayHit> hits = trace(bvh, rays, false);
  std::vector<GpuRayHit> occ = trace(bvh, rays, true);
  size_t misses = 0;
  for (size_t i = 0; i < rays.size(); ++i) misses += hits[i].t_uv.w != 1.0f || occ[i].t_uv.w != 1.0f;
  EXPECT_EQ(misses, 0u) << "of " << rays.size() << " rays at shared vertices and edges";
}

TEST_F(BvhGpu, InvalidRaysAndEmptyBvhMiss) {
  EXPECT_TRUE(ctx().validation_enabled()) << "the Khronos validation layer must be on for these tests";
  TestScene s = test_scene();
  Bvh bvh = build_bvh(s.triangles);
  const glm::vec3 o(-2, 0, 3), d(0, 0, -1);  // straight at the first sphere
  std::vector<GpuRay> rays = {
      make_ray(o, d, 0, kInf),                // valid: hits
      make_ray({kNaN, 0, 3}, d, 0, kInf),     // NaN origin
      make_ray(o, {0, kNaN, -1}, 0, kInf),    // NaN direction
      make_ray(o, d, kNaN, kInf),             // NaN tmin
      make_ray(o, d, 0, kNaN),                // NaN tmax
      make_ray({kInf, 0, 3}, d, 0, kInf),     // infinite origin
      make_ray(o, {0, 0, -kInf}, 0, kInf),    // infinite direction
      make_ray(o, {0, 0, 0}, 0, kInf),        // zero direction
      make_ray(o, d, 5, 1),                   // tmin > tmax
      make_ray(o, d, 0, 1.5f),                // ends before the sphere (at t = 2)
      make_ray(o, d, 2.5f, kInf),             // starts inside: the far side at t = 4
      make_ray(o, {0, 0, -1e-20f}, 0, kInf),  // tiny direction: still a valid ray
  };
  std::vector<GpuRayHit> hits = trace(bvh, rays, false);
  std::vector<GpuRayHit> occ = trace(bvh, rays, true);
  const bool expect_hit[] = {true, false, false, false, false, false, false, false, false, false, true, true};
  for (size_t i = 0; i < rays.size(); ++i) {
    EXPECT_EQ(hits[i].t_uv.w == 1.0f, expect_hit[i]) << "ray " << i;
    EXPECT_EQ(occ[i].t_uv.w == 1.0f, expect_hit[i]) << "ray " << i;
  }
  EXPECT_NEAR(hits[0].t_uv.x, 2.0f, 2e-3f);
  EXPECT_EQ(hits[0].ids.y, 0u);  // instance 0, the sphere
  EXPECT_NEAR(hits[0].normal.z, 1.0f, 1e-2f);
  EXPECT_NEAR(hits[10].t_uv.x, 4.0f, 2e-3f);
  EXPECT_NEAR(hits[10].normal.z, -1.0f, 1e-2f);  // the far side's outward normal, not turned to the ray
  EXPECT_NEAR(hits[11].t_uv.x, 2e20f, 2e17f);

  Bvh empty = build_bvh({});
  std::vector<GpuRayHit> none = trace(empty, rays, false);
  std::vector<GpuRayHit> none_occ = trace(empty, rays, true);
  for (size_t i = 0; i < rays.size(); ++i) {
    EXPECT_NE(none[i].t_uv.w, 1.0f) << "ray " << i;
    EXPECT_NE(none_occ[i].t_uv.w, 1.0f) << "ray " << i;
  }
}

// Shading normals are kept only for meshes whose vertex normals differ from their triangles' normals (the
// sphere, an OBJ with smooth vn), per BVH triangle in leaf order, in world space; a triangle with a zero
// vertex normal shades with its geometric normal, and a note says how many.
TEST(SceneGeometry, ShadingNormalsOnlyWhereMeshesAreSmooth) {
  EXPECT_FALSE(smooth_normals(box(glm::vec3(1, 2, 3))));
  EXPECT_FALSE(smooth_normals(plane(glm::vec2(2, 1))));
  EXPECT_FALSE(smooth_normals(window(1, 1, 0.1f, 4, 0.02f, 30)));
  EXPECT_TRUE(smooth_normals(sphere(1, 8)));
  auto geometry = [](const nlohmann::json& surfaces) {
    return build_geometry(scene::from_json({{"surfaces", surfaces}}, "scene.json", ""));
  };
  const SceneGeometry flat = geometry({{{"mesh", {{"kind", "box"}}}}, {{"mesh", {{"kind", "plane"}}}}});
  EXPECT_TRUE(flat.triangle_normals.empty());

  // A sphere turned by 90 degrees about z next to a box: the box's triangles carry no normals, the
  // sphere's carry its radial directions turned likewise.
  const SceneGeometry g = geometry({{{"mesh", {{"kind", "box"}}}},
                                    {{"mesh", {{"kind", "sphere"}, {"segments", 8}}},
                                     {"transform", {{"rotate", {0, 0, 90}}, {"translate", {5, 0, 0}}}}}});
  ASSERT_EQ(g.triangle_normals.size(), g.bvh.triangles.size());
  size_t sphere_triangles = 0;
  for (size_t k = 0; k < g.bvh.triangles.size(); ++k) {
    const glsl::GpuTriangle& t = g.bvh.triangles[k];
    const glm::uvec4 n = g.triangle_normals[k].n012;
    if (instance_id(t) == 0) {
      EXPECT_EQ(n, glm::uvec4(0));
      continue;
    }
    ++sphere_triangles;
    EXPECT_EQ(n.w, 1u);
    const glm::vec3 corner[3] = {glm::vec3(t.v0), glm::vec3(t.v1), glm::vec3(t.v2)};
    for (int i = 0; i < 3; ++i) {
      const glm::vec3 decoded = glsl::oct_decode(glm::unpackSnorm2x16(n[i]));
      EXPECT_GT(glm::dot(decoded, glm::normalize(corner[i] - glm::vec3(5, 0, 0))), 0.99999f) << k << " " << i;
    }
  }
  EXPECT_EQ(sphere_triangles, sphere(0.5f, 8).triangles.size());

  // An OBJ with one zero normal: its triangle falls back to the geometric normal and is counted.
  const auto dir = temp_root() / "normals";
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "zero_vn.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
                                        "vn 0 0 1\nvn 0.2 0 1\nvn 0 0 0\n"
                                        "f 1//1 2//2 3//1\nf 2//2 4//3 3//1\n";
  const SceneGeometry z = geometry({{{"file", (dir / "zero_vn.obj").string()}}});
  ASSERT_EQ(z.triangle_normals.size(), 2u);
  int set = 0;
  for (const auto& t : z.triangle_normals) set += int(t.n012.w);
  EXPECT_EQ(set, 1);
  ASSERT_EQ(z.notes.size(), 1u);
  EXPECT_NE(z.notes[0].find("surfaces[0]: 1 triangles have a zero or non-finite vertex normal"),
            std::string::npos)
      << z.notes[0];
}

}  // namespace
}  // namespace haze::surfaces
