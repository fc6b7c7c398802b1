// The viewer's parts without a window: camera controls against closed forms, scripts and their one-line
// errors, the parameter panel drawn from reflect() (every key gets a widget; edits are checked as scene
// files), and the layer display pass on the device against the renderer's own outputs and CPU code.
#include <gtest/gtest.h>
#include <imgui.h>

#include <cmath>
#include <glm/glm.hpp>
#include <glm/gtc/constants.hpp>

#include "expect_error.hpp"
#include "render/output.hpp"
#include "test_util.hpp"
#include "view/camera.hpp"
#include "view/layers.hpp"
#include "view/panel.hpp"
#include "view/script.hpp"

namespace haze {
namespace {

using view::CameraController;
using view::CameraInput;
using view::CameraMode;

constexpr float kPi = glm::pi<float>();

scene::Camera camera_at(glm::vec3 position, glm::vec3 target) {
  scene::Camera c;
  c.position = position;
  c.target = target;
  return c;
}

// Fly: WASD moves along the view's axes at a quarter of the scene's extent per second (4x with shift), and
// the target moves with the eye. Injected defect caught: the right vector as up x forward (A and D swapped).
TEST(ViewCamera, FlyMovesAlongTheViewAtTheSceneSpeed) {
  CameraController c(camera_at({0, 1, 5}, {0, 1, 0}), 8.f);  // extent 8: 2 units per second
  EXPECT_FLOAT_EQ(c.speed(), 2.f);
  CameraInput in;
  in.move = {0, 0, 1};  // W
  in.dt = 0.5;
  ASSERT_TRUE(c.update(in, CameraMode::Fly));
  EXPECT_NEAR(glm::distance(c.camera().position, glm::vec3(0, 1, 4)), 0, 1e-6f);
  EXPECT_NEAR(glm::distance(c.camera().target, glm::vec3(0, 1, -1)), 0, 1e-6f);
  in.move = {1, 0, 0};  // D: to the right of a camera looking down -z is +x
  in.fast = true;
  c.update(in, CameraMode::Fly);
  EXPECT_NEAR(glm::distance(c.camera().position, glm::vec3(4, 1, 4)), 0, 1e-5f);
  EXPECT_FALSE(c.update(CameraInput{}, CameraMode::Fly));  // no input, no change
}

// Mouse look turns the view by kLookRadiansPerPixel per pixel about the up axis, keeping the distance to the
// target; moving right turns right. Pitch stops 1 degree short of the up axis. Injected defect caught: the
// yaw's sign (the view turned left).
TEST(ViewCamera, LookTurnsByTheMouseAndStopsShortOfTheUpAxis) {
  CameraController c(camera_at({0, 0, 0}, {0, 0, -2}), 1.f);
  CameraInput in;
  in.look = {kPi / 2 / CameraController::kLookRadiansPerPixel, 0};  // a quarter turn to the right
  c.update(in, CameraMode::Fly);
  EXPECT_NEAR(glm::distance(c.camera().target, glm::vec3(2, 0, 0)), 0, 1e-5f);
  in.look = {0, -10.f / CameraController::kLookRadiansPerPixel};  // far past straight up
  c.update(in, CameraMode::Fly);
  const glm::vec3 dir = glm::normalize(c.camera().target - c.camera().position);
  EXPECT_NEAR(std::acos(dir.y), glm::radians(1.f), 1e-4f);
  EXPECT_NEAR(glm::distance(c.camera().target, c.camera().position), 2.f, 1e-5f);
}

// Orbit keeps the target and the distance while the eye goes round; the wheel scales the distance by 0.9 a
// step. Injected defect caught: orbiting about the eye (the target moved).
TEST(ViewCamera, OrbitKeepsTheTargetAndZoomScalesTheDistance) {
  CameraController c(camera_at({0, 1, 5}, {0, 1, 0}), 1.f);
  CameraInput in;
  in.look = {kPi / CameraController::kLookRadiansPerPixel, 0};  // half way round
  c.update(in, CameraMode::Orbit);
  EXPECT_NEAR(glm::distance(c.camera().target, glm::vec3(0, 1, 0)), 0, 1e-6f);
  EXPECT_NEAR(glm::distance(c.camera().position, glm::vec3(0, 1, -5)), 0, 1e-4f);
  in = CameraInput{};
  in.zoom = 2;
  c.update(in, CameraMode::Orbit);
  EXPECT_NEAR(glm::distance(c.camera().position, c.camera().target), 5.f * 0.81f, 1e-4f);
}

scene::Scene small_scene() {
  return test::make_scene(
      {{"camera", {{"position", {0, 1, 5}}, {"target", {0, 1, 0}}}},
       {"haze",
        {{"sigma_t", 0.2}, {"bounded", true}, {"bounds_min", {-3, -1, -3}}, {"bounds_max", {3, 3, 3}}}},
       {"surfaces", {{{"mesh", {{"kind", "plane"}, {"size", {4, 4}}}}}}},
       {"lights", {{"sun", {{"direction", {0.3, 1, 0.2}}}}}},
       {"render", {{"width", 24}, {"height", 16}}}});
}

// A script's entries in frame order, each with the scene it leads to; camera-only entries are marked so
// the viewer takes the renderer's fast path. Injected defect caught: entries kept in file order.
TEST(ViewScript, EntriesBecomeScenesInFrameOrder) {
  const scene::Scene s = small_scene();
  auto steps = view::parse_script(R"([
      {"frame": 5, "set": {"render.exposure": 2}, "layer": "volume", "ui": false},
      {"frame": 1, "camera": {"position": [1, 2, 3]}, "screenshot": "a.png"}])",
                                  "s.json", s, 10, view::layer_names());
  ASSERT_EQ(steps.size(), 2u);
  EXPECT_EQ(steps[0].entry.frame, 1);
  EXPECT_TRUE(steps[0].camera_only);
  EXPECT_EQ(steps[0].scene.camera.position, glm::vec3(1, 2, 3));
  EXPECT_EQ(steps[1].entry.frame, 5);
  EXPECT_FALSE(steps[1].camera_only);
  EXPECT_FLOAT_EQ(steps[1].scene.render.exposure, 2.f);
  EXPECT_EQ(steps[1].scene.camera.position, glm::vec3(1, 2, 3));  // the earlier entry's camera stays
  EXPECT_EQ(steps[1].ui, std::optional<bool>(false));
  EXPECT_EQ(steps[1].entry.layer, "volume");
}

// Bad scripts fail as scene files do: one line naming the file, the entry and the key, before any window.
// Injected defect caught: no check of a frame beyond --frames (the entry was silently never applied).
TEST(ViewScript, BadScriptsGetOneLineErrors) {
  const scene::Scene s = small_scene();
  const auto names = view::layer_names();
  auto parse = [&](const std::string& text) {
    return [&, text] { view::parse_script(text, "s.json", s, 10, names); };
  };
  test::expect_error(parse("[{\"frame\": 1,}]"), {"s.json: line 1", "malformed JSON"});
  test::expect_error(parse("{\"frame\": 1}"), {"s.json: (top level)", "list of entries"});
  test::expect_error(parse("[{\"frmae\": 1}]"), {"s.json: [0].frmae", "did you mean \"frame\""});
  test::expect_error(parse("[{\"set\": {}}]"), {"s.json: [0].frame", "required"});
  test::expect_error(parse("[{\"frame\": 12}]"), {"s.json: [0].frame", "never reached", "--frames 10"});
  test::expect_error(parse("[{\"frame\": 1, \"layer\": \"voulme\"}]"),
                     {"s.json: [0].layer", "\"voulme\" is not a layer"});
  test::expect_error(parse("[{\"frame\": 1, \"ui\": 1}]"), {"s.json: [0].ui", "true or false"});
  test::expect_error(parse("[{\"frame\": 1, \"frame\": 2}]"), {"s.json: [0].frame", "appears twice"});
  test::expect_error(parse("[{\"frame\": 1, \"camera\": {\"positon\": [0, 0, 0]}}]"),
                     {"s.json: [0]", "camera.positon", "did you mean \"position\""});
  test::expect_error(parse("[{\"frame\": 1}, {\"frame\": 2, \"set\": {\"render.spp\": 0}}]"),
                     {"s.json: [1]", "render.spp", "must be in [1,"});
  // Cross-field checks see the state the earlier entries left.
  test::expect_error(parse("[{\"frame\": 1, \"camera\": {\"position\": [0, 1, 0]}}]"),
                     {"s.json: [0]", "camera.target"});
}

// Every key of the scene's reflect() declarations gets a widget (paths of list elements at [0]), except
// those a live view leaves out; ImGui runs headless (no backend) for this. Injected defect caught: the
// [x, y, z] keys left without a widget (25 paths listed as missing).
TEST(ViewPanel, EveryDeclaredKeyHasAWidget) {
  scene::Scene s = test::make_scene({{"media", {{{"procedural", {{"kind", "sphere"}}}}}},
                                     {"surfaces", {{{"mesh", {{"kind", "plane"}}}}}},
                                     {"haze", nlohmann::json::object()},
                                     {"lights",
                                      {{"sun", nlohmann::json::object()},
                                       {"points", {nlohmann::json::object()}},
                                       {"spots", {nlohmann::json::object()}},
                                       {"environment", nlohmann::json::object()}}}});
  // Optional groups a procedural medium cannot hold are drawn present (the panel does not validate).
  s.media[0].velocity.emplace();
  ImGui::CreateContext();
  ImGuiIO& io = ImGui::GetIO();
  io.IniFilename = nullptr;
  io.DisplaySize = ImVec2(800, 600);
  unsigned char* pixels = nullptr;
  int w = 0, h = 0;
  io.Fonts->GetTexDataAsRGBA32(&pixels, &w, &h);
  ImGui::NewFrame();
  ImGui::Begin("test");
  std::vector<std::string> drawn;
  const view::PanelEdit edit = view::draw_parameters(s, &drawn);
  ImGui::End();
  ImGui::Render();
  ImGui::DestroyContext();
  EXPECT_FALSE(edit.changed);
  std::vector<std::string> missing;
  for (const auto& p : scene::describe()) {
    std::string path = p.path;
    for (size_t at; (at = path.find("[]")) != std::string::npos;) path.replace(at, 2, "[0]");
    const bool left_out = path.rfind("animation", 0) == 0 || path == "render.frames" ||
                          path == "render.outputs" || path == "render.fps";
    if (left_out) continue;
    if (std::find(drawn.begin(), drawn.end(), path) == drawn.end()) missing.push_back(path);
  }
  EXPECT_TRUE(missing.empty()) << "no widget for " << ::testing::PrintToString(missing);
  EXPECT_GT(drawn.size(), 150u);
}

// An edit reaches the renderer only as a valid scene: reflect's reader and validate() run on it and a bad
// one is refused with the reader's one-line error. Injected defect caught: the edited scene passed on
// unread.
TEST(ViewPanel, EditsAreCheckedAsSceneFiles) {
  scene::Scene s = small_scene();
  s.render.exposure = 3.f;
  EXPECT_FLOAT_EQ(view::check_edit(s).render.exposure, 3.f);
  s.camera.target = s.camera.position;
  test::expect_error([&] { view::check_edit(s); }, {"camera.target", "equals camera.position"});
}

// The layer display pass against the renderer's outputs: "final" is the preview byte for byte, "noisy" is
// the mean through the preview's exposure, tone curve and sRGB (render::preview_srgb8, CPU) within one
// step of 8 bits, "surface_history" is the history length / max_history as grey. Injected defects caught:
// the colour read at the volume term's offset (44 steps off), and the exposure left out (36 steps off).
TEST(ViewLayers, DisplayMatchesTheRenderersOutputs) {
  gpu::Context& ctx = test::context();
  scene::Scene s = small_scene();
  s.render.exposure = 0.7f;
  render::Renderer r(ctx, s);
  r.add_samples(2);
  const render::Image img = r.resolve();
  view::LayerDisplay display(ctx);
  const size_t pixels = size_t(s.render.width) * s.render.height;
  gpu::Buffer out(ctx, "test display", "test", pixels * 4);
  auto show = [&](const std::string& layer) {
    EXPECT_TRUE(view::LayerDisplay::available(r, layer)) << layer;
    ctx.submit_and_wait([&](VkCommandBuffer cmd) { display.record(cmd, nullptr, r, layer, 10.f, out); });
    return out.download_vector<uint32_t>();
  };
  EXPECT_EQ(show("final"), img.ldr);

  std::vector<float> rgb(pixels * 3);
  for (size_t p = 0; p < pixels; ++p)
    for (int c = 0; c < 3; ++c) rgb[p * 3 + c] = img.data[p * glsl::OUT_STRIDE + glsl::OUT_L + c];
  const std::vector<uint32_t> want = render::preview_srgb8(rgb, s.render.exposure, s.render.tonemap);
  uint32_t brightest = 0;
  for (uint32_t v : want) brightest = std::max(brightest, v & 255u);
  EXPECT_GT(brightest, 100u) << "the test scene renders (nearly) black";
  const std::vector<uint32_t> noisy = show("noisy");
  int worst = 0;
  for (size_t p = 0; p < pixels; ++p)
    for (int c = 0; c < 3; ++c)
      worst = std::max(worst, std::abs(int((noisy[p] >> (8 * c)) & 255) - int((want[p] >> (8 * c)) & 255)));
  EXPECT_LE(worst, 1);

  ASSERT_TRUE(img.surface_denoised);
  const std::vector<uint32_t> history = show("surface_history");
  for (size_t p = 0; p < pixels; ++p) {
    const float g = std::clamp(img.surface_denoised->history[p] / s.denoise.surface.max_history, 0.f, 1.f);
    const std::vector<uint32_t> grey = render::preview_srgb8({g, g, g}, 0.f, "clamp");
    EXPECT_NEAR(int(history[p] & 255), int(grey[0] & 255), 1) << "pixel " << p;
  }
  EXPECT_FALSE(view::LayerDisplay::available(r, "guide_mean"));  // guiding is off
  EXPECT_EQ(ctx.validation_messages(), 0u);
}

}  // namespace
}  // namespace haze
