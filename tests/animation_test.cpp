// Keyframed animation (scene/animation.hpp): interpolation, tracks into every kind of parameter, VDB
// sequences, load-time errors that name their JSON path, --frames.
#include "scene/animation.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <glm/geometric.hpp>
#include <glm/vec4.hpp>
#include <initializer_list>
#include <sstream>
#include <string>

#include "expect_error.hpp"
#include "temp_dir.hpp"

namespace fs = std::filesystem;
using haze::scene::Error;
using haze::scene::Scene;
using nlohmann::json;
namespace hs = haze::scene;

namespace {

using haze::test::expect_error;
using haze::test::read_error;

json sphere_medium() {
  return {{"procedural", {{"kind", "sphere"}}}};
}

json key(int frame, json value) {
  return {{"frame", frame}, {"value", std::move(value)}};
}

// Lists as std::vector: a braced list of one json would be that element, not an array of it.
json track(const std::string& path, std::vector<json> keys, const std::string& interpolation = "linear") {
  return {{"path", path}, {"interpolation", interpolation}, {"keys", json(std::move(keys))}};
}

// A scene with one medium, every light kind, and the given tracks.
json animated(std::vector<json> tracks) {
  json j = {{"media", {sphere_medium()}},
            {"lights",
             {{"sun", {{"direction", {0, 1, 0}}}},
              {"points", {{{"position", {0, 2, 0}}}}},
              {"spots", {{{"position", {0, 4, 0}}}}},
              {"environment", {{"color", {0.1, 0.2, 0.3}}}}}}};
  j["animation"] = {{"tracks", json(std::move(tracks))}};
  return j;
}

Scene read(const json& j) {
  return hs::from_json(j, "scene.json", "");
}

// The value of a one-track scalar animation at `frame`.
float scalar_at(const std::vector<json>& keys, const std::string& interpolation, int frame) {
  Scene s = read(animated({track("lights.sun.irradiance", keys, interpolation)}));
  return hs::scene_at_frame(s, frame).lights.sun->irradiance;
}

// Each test's files live in its own folder.
struct AnimationDir : haze::test::TempDir {
  AnimationDir() : haze::test::TempDir("haze_animation_test") {}
};

}  // namespace

// ---- interpolation ----

TEST(AnimationInterpolation, LinearAtBetweenAndOutsideKeys) {
  std::vector<json> keys = {key(10, 1), key(20, 3), key(40, 2)};
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 0), 1);  // hold before the first key
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", -5), 1);
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 10), 1);
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 15), 2);
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 20), 3);
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 30), 2.5f);
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 40), 2);
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 1000), 2);  // hold after the last key
  // One key: a constant.
  EXPECT_FLOAT_EQ(scalar_at({key(5, 7)}, "linear", 0), 7);
  EXPECT_FLOAT_EQ(scalar_at({key(5, 7)}, "smooth", 99), 7);
}

TEST(AnimationInterpolation, SmoothBetweenTwoKeysIsSmoothstep) {
  std::vector<json> keys = {key(0, 0), key(4, 1)};
  EXPECT_FLOAT_EQ(scalar_at(keys, "smooth", 0), 0);
  EXPECT_FLOAT_EQ(scalar_at(keys, "smooth", 1), 0.15625f);  // 3s^2 - 2s^3 at s = 1/4
  EXPECT_FLOAT_EQ(scalar_at(keys, "smooth", 2), 0.5f);
  EXPECT_FLOAT_EQ(scalar_at(keys, "smooth", 3), 0.84375f);
  EXPECT_FLOAT_EQ(scalar_at(keys, "smooth", 4), 1);
  EXPECT_FLOAT_EQ(scalar_at(keys, "smooth", 9), 1);
  EXPECT_FLOAT_EQ(scalar_at(keys, "smooth", -1), 0);
  // Linear for comparison.
  EXPECT_FLOAT_EQ(scalar_at(keys, "linear", 1), 0.25f);
}

TEST(AnimationInterpolation, SmoothKeepsMovingThroughInnerKeys) {
  // On a straight line the inner key's slope is the line's: the curve does not stop at frame 10.
  std::vector<json> keys = {key(0, 0), key(10, 10), key(20, 20)};
  float before = scalar_at(keys, "smooth", 9), at = scalar_at(keys, "smooth", 10),
        after = scalar_at(keys, "smooth", 11);
  EXPECT_FLOAT_EQ(at, 10);
  EXPECT_NEAR(before, 8.91f, 1e-5);  // Hermite with slopes 0 and 1
  EXPECT_NEAR(after, 11.09f, 1e-5);
  EXPECT_NEAR(at - before, after - at, 1e-5);  // same speed on both sides: C1
}

TEST(AnimationInterpolation, SmoothNeverOvershoots) {
  // Up, down, up: the values stay between the two keys around each frame, with a flat top at the
  // turning points.
  std::vector<json> keys = {key(0, 0), key(10, 1), key(13, 0.2), key(30, 0.9)};
  for (int f = 0; f <= 30; ++f) {
    float v = scalar_at(keys, "smooth", f);
    float lo = f <= 10 ? 0.f : 0.2f, hi = f <= 13 ? 1.f : 0.9f;
    EXPECT_GE(v, lo) << "frame " << f;
    EXPECT_LE(v, hi) << "frame " << f;
  }
  EXPECT_LT(scalar_at(keys, "smooth", 9), 1);
  EXPECT_LT(scalar_at(keys, "smooth", 11), 1);
  // Ranges that hold at the keys hold everywhere: albedo near its upper bound 1.
  Scene s = read(animated(
      {track("media[0].albedo", {key(0, {0, 0.5, 1}), key(5, {1, 1, 1}), key(9, {0, 0, 1})}, "smooth")}));
  for (int f = 0; f <= 9; ++f) {
    glm::vec3 a = hs::scene_at_frame(s, f).media[0].albedo;
    for (int i = 0; i < 3; ++i) {
      EXPECT_GE(a[i], 0) << f;
      EXPECT_LE(a[i], 1) << f;
    }
  }
}

TEST(AnimationInterpolation, Vec3AndComponentTracks) {
  Scene s = read(animated({
      track("camera.position", {key(0, {0, 1, 5}), key(10, {4, 3, 1})}),
      track("camera.fov_y", {key(0, 40), key(10, 60)}, "smooth"),
      track("camera.target[1]", {key(0, 1), key(10, 2)}),
  }));
  Scene f5 = hs::scene_at_frame(s, 5);
  EXPECT_EQ(f5.camera.position, glm::vec3(2, 2, 3));
  EXPECT_FLOAT_EQ(f5.camera.fov_y, 50);
  EXPECT_EQ(f5.camera.target, glm::vec3(0, 1.5f, 0));
  EXPECT_EQ(hs::scene_at_frame(s, 0).camera.position, glm::vec3(0, 1, 5));
  EXPECT_EQ(hs::scene_at_frame(s, 10).camera.position, glm::vec3(4, 3, 1));
  EXPECT_EQ(hs::scene_at_frame(s, 11).camera.target, glm::vec3(0, 2, 0));
  // The dotted form of a component path works too.
  Scene t = read(animated({track("camera.position.0", {key(0, 0), key(2, 1)})}));
  EXPECT_EQ(hs::scene_at_frame(t, 1).camera.position, glm::vec3(0.5f, 1, 5));
}

TEST(AnimationTracks, MediumTransformsAndDensity) {
  Scene s = read(animated({
      track("media[0].transform.translate", {key(0, {0, 0, 0}), key(10, {10, 0, 0})}),
      track("media[0].transform.rotate", {key(0, {0, 0, 0}), key(10, {0, 0, 180})}),
      track("media[0].transform.scale", {key(0, {1, 1, 1}), key(10, {3, 3, 3})}),
      track("media.0.density_scale", {key(0, 1), key(10, 0)}),
      track("media[0].emission.scale", {key(0, 0), key(10, 4)}),
  }));
  Scene f5 = hs::scene_at_frame(s, 5);
  const hs::Transform& t = f5.media[0].transform;
  EXPECT_EQ(t.translate, glm::vec3(5, 0, 0));
  EXPECT_EQ(t.rotate, glm::vec3(0, 0, 90));
  EXPECT_EQ(t.scale, glm::vec3(2, 2, 2));
  glm::vec4 p = t.matrix() * glm::vec4(1, 0, 0, 1);  // scaled to 2, turned onto +y, moved by 5 in x
  EXPECT_NEAR(p.x, 5, 1e-5);
  EXPECT_NEAR(p.y, 2, 1e-5);
  EXPECT_FLOAT_EQ(f5.media[0].density_scale, 0.5f);
  EXPECT_FLOAT_EQ(f5.media[0].emission.scale, 2);
  // Untouched values are kept.
  EXPECT_EQ(f5.media[0].albedo, s.media[0].albedo);
  EXPECT_EQ(f5.camera.position, s.camera.position);
}

TEST(AnimationTracks, Lights) {
  Scene s = read(animated({
      track("lights.sun.direction", {key(0, {0, 1, 0}), key(10, {2, 0, 0})}),
      track("lights.sun.irradiance", {key(0, 5), key(10, 1)}),
      track("lights.points[0].position", {key(0, {0, 2, 0}), key(10, {0, 2, 10})}),
      track("lights.points[0].intensity", {key(0, 10), key(10, 30)}),
      track("lights.spots[0].position", {key(0, {0, 4, 0}), key(10, {2, 4, 0})}),
      track("lights.spots[0].intensity", {key(0, 10), key(10, 0)}),
      track("lights.spots[0].direction", {key(0, {0, -1, 0}), key(10, {1, -1, 0})}),
      track("lights.environment.intensity", {key(0, 1), key(10, 3)}),
  }));
  Scene f5 = hs::scene_at_frame(s, 5);
  // Directions are interpolated as given ([1, 0.5, 0] halfway) and normalised, as on load.
  EXPECT_NEAR(glm::length(f5.lights.sun->direction), 1, 1e-6);
  glm::vec3 expected = glm::normalize(glm::vec3(1, 0.5f, 0));
  EXPECT_NEAR(f5.lights.sun->direction.x, expected.x, 1e-6);
  EXPECT_NEAR(f5.lights.sun->direction.y, expected.y, 1e-6);
  EXPECT_FLOAT_EQ(f5.lights.sun->irradiance, 3);
  EXPECT_EQ(f5.lights.points[0].position, glm::vec3(0, 2, 5));
  EXPECT_FLOAT_EQ(f5.lights.points[0].intensity, 20);
  EXPECT_EQ(f5.lights.spots[0].position, glm::vec3(1, 4, 0));
  EXPECT_FLOAT_EQ(f5.lights.spots[0].intensity, 5);
  EXPECT_NEAR(glm::length(f5.lights.spots[0].direction), 1, 1e-6);
  EXPECT_FLOAT_EQ(f5.lights.environment->intensity, 2);
  // A haze and the PNG exposure are animatable too.
  json j = animated(
      {track("haze.sigma_t", {key(0, 0.1), key(2, 0.3)}), track("render.exposure", {key(0, 0), key(2, -2)})});
  j["haze"] = json::object();
  Scene h = hs::scene_at_frame(read(j), 1);
  EXPECT_FLOAT_EQ(h.haze->sigma_t, 0.2f);
  EXPECT_FLOAT_EQ(h.render.exposure, -1);
}

// ---- the evaluated scene ----

TEST(AnimationFrames, StaticSceneIsUnchanged) {
  json j = {{"camera", {{"position", {1, 2, 3}}, {"target", {0, 0.5, 0}}, {"fov_y", 30}}},
            {"media", {sphere_medium(), {{"file", "/data/cloud.vdb"}, {"density_scale", 2}}}},
            {"lights", {{"sun", {{"direction", {1, 2, 0.5}}}}, {"points", {{{"intensity", 5}}}}}},
            {"render", {{"frames", "3:9"}, {"spp", 4}}}};
  Scene s = read(j);
  EXPECT_FALSE(hs::is_animated(s));
  for (int f : {0, 5, 1000}) {
    Scene at = hs::scene_at_frame(s, f);
    EXPECT_EQ(hs::to_json(at), hs::to_json(s));
    EXPECT_EQ(at.lights.sun->direction, s.lights.sun->direction);  // bit for bit, not renormalised
    EXPECT_EQ(at.path, s.path);
    EXPECT_EQ(at.media[1].file, "/data/cloud.vdb");
  }
  // An empty animation is no animation.
  j["animation"] = {{"tracks", json::array()}};
  Scene e = read(j);
  EXPECT_FALSE(hs::is_animated(e));
  EXPECT_EQ(hs::to_json(hs::scene_at_frame(e, 4)), hs::to_json(e));
}

TEST(AnimationFrames, ResultIsAStaticScene) {
  json j = animated({track("camera.position", {key(0, {0, 1, 5}), key(10, {0, 1, 7})})});
  j["media"].push_back({{"file", "/data/smoke_###.vdb"}});
  Scene s = read(j);
  EXPECT_TRUE(hs::is_animated(s));
  Scene f3 = hs::scene_at_frame(s, 3);
  EXPECT_FALSE(f3.animation);
  EXPECT_FALSE(hs::is_animated(f3));
  EXPECT_EQ(f3.media[1].file, "/data/smoke_003.vdb");
  EXPECT_EQ(f3.path, "scene.json");
  // It reads back as the same static scene.
  EXPECT_EQ(hs::to_json(read(hs::to_json(f3))), hs::to_json(f3));
  // The original is untouched.
  EXPECT_EQ(s.media[1].file, "/data/smoke_###.vdb");
  EXPECT_EQ(s.camera.position, glm::vec3(0, 1, 5));
}

TEST(AnimationFrames, EachFrameIsIndependentAndRepeatable) {
  Scene s = read(animated({
      track("camera.position", {key(0, {0, 1, 5}), key(7, {1, 2, 3}), key(20, {4, 1, 0})}, "smooth"),
      track("media[0].transform.rotate", {key(0, {0, 0, 0}), key(20, {10, 20, 30})}, "smooth"),
  }));
  // Frame k - 1 for motion vectors: the same whether evaluated before, after or alone.
  json prev = hs::to_json(hs::scene_at_frame(s, 11));
  json cur = hs::to_json(hs::scene_at_frame(s, 12));
  for (int f = 20; f >= 0; --f) hs::scene_at_frame(s, f);
  EXPECT_EQ(hs::to_json(hs::scene_at_frame(s, 11)), prev);
  EXPECT_EQ(hs::to_json(hs::scene_at_frame(s, 12)), cur);
  EXPECT_NE(prev, cur);
  // Frame 0 has a previous frame too: the hold.
  EXPECT_EQ(hs::to_json(hs::scene_at_frame(s, -1)), hs::to_json(hs::scene_at_frame(s, 0)));
}

TEST(AnimationFrames, RangeAndTime) {
  EXPECT_EQ(hs::frame_range(read(json::object())), std::make_pair(0, 0));
  Scene s = read(animated({track("camera.fov_y", {key(5, 40), key(30, 50)}),
                           track("lights.sun.irradiance", {key(12, 1), key(48, 2)})}));
  EXPECT_EQ(hs::frame_range(s), std::make_pair(5, 48));  // the span of all keys
  json j = animated({track("camera.fov_y", {key(5, 40), key(30, 50)})});
  j["render"] = {{"frames", "0:99"}, {"fps", 25}};
  Scene r = read(j);
  EXPECT_EQ(hs::frame_range(r), std::make_pair(0, 99));
  EXPECT_DOUBLE_EQ(hs::frame_time(r, 50), 2.0);
  EXPECT_EQ(hs::frame_range(read({{"render", {{"frames", "7"}}}})), std::make_pair(7, 7));
  EXPECT_DOUBLE_EQ(hs::frame_time(Scene{}, 12), 0.5);  // 24 fps by default
}

TEST(AnimationJson, RoundTripKeepsTheAnimation) {
  json j = animated({
      track("camera.position", {key(0, {0, 1, 5}), key(119, {3, 1, 2})}, "smooth"),
      track("media[0].density_scale", {key(10, 0.5), key(20, 2.5)}),
  });
  j["render"] = {{"frames", "0:119"}, {"fps", 30}};
  Scene s = read(j);
  json a = hs::to_json(s);
  ASSERT_TRUE(a.contains("animation"));
  EXPECT_EQ(a["animation"]["tracks"][0]["path"], "camera.position");
  EXPECT_EQ(a["animation"]["tracks"][0]["interpolation"], "smooth");
  EXPECT_EQ(a["animation"]["tracks"][1]["keys"][1], key(20, 2.5));
  EXPECT_EQ(a["render"]["frames"], "0:119");
  Scene back = read(a);
  EXPECT_EQ(hs::to_json(back), a);
  for (int f : {0, 15, 60, 119})
    EXPECT_EQ(hs::to_json(hs::scene_at_frame(back, f)), hs::to_json(hs::scene_at_frame(s, f)));
  // A scene without animation writes none.
  EXPECT_FALSE(hs::to_json(Scene{}).contains("animation"));
}

TEST(AnimationJson, OverridesReachIntoTracks) {
  json j = animated({track("camera.position", {key(0, {0, 1, 5}), key(10, {0, 1, 7})})});
  hs::apply_override(j, "animation.tracks.0.keys.1.value=[2, 1, 7]", "scene.json");
  hs::apply_override(j, "animation.tracks[0].interpolation=smooth", "scene.json");
  Scene s = read(j);
  EXPECT_EQ(s.animation->tracks[0].interpolation, "smooth");
  EXPECT_EQ(hs::scene_at_frame(s, 10).camera.position, glm::vec3(2, 1, 7));
  hs::apply_override(j, "animation=null", "scene.json");
  EXPECT_FALSE(read(j).animation);
  // A bad value from --set names the override.
  AnimationDir dir;
  json file = animated({track("camera.fov_y", {key(0, 40), key(10, 50)})});
  fs::path p = dir.write("s.json", file.dump());
  expect_error(
      [&] { hs::load(p.string(), {"animation.tracks.0.keys.1.value=200"}); },
      {"animation.tracks[0].keys[1].value", "(0, 180)", "--set animation.tracks.0.keys.1.value=200"});
}

// ---- VDB sequences ----

TEST(AnimationSequence, FilePattern) {
  EXPECT_TRUE(hs::is_sequence("smoke_####.vdb"));
  EXPECT_FALSE(hs::is_sequence("smoke.vdb"));
  EXPECT_EQ(hs::frame_file("smoke_####.vdb", 7), "smoke_0007.vdb");
  EXPECT_EQ(hs::frame_file("smoke_####.vdb", 0), "smoke_0000.vdb");
  EXPECT_EQ(hs::frame_file("smoke_####.vdb", 12345), "smoke_12345.vdb");  // wider numbers in full
  EXPECT_EQ(hs::frame_file("smoke_####.vdb", -1), "smoke_-001.vdb");      // like printf's %04d
  EXPECT_EQ(hs::frame_file("/a/b/f#.vdb", 3), "/a/b/f3.vdb");
  EXPECT_EQ(hs::frame_file("#.vdb", 42), "42.vdb");
  EXPECT_EQ(hs::frame_file("smoke.vdb", 7), "smoke.vdb");
  read_error({{"media", {{{"file", "s_##_##.vdb"}}}}}, {"scene.json: media[0].file", "2 runs of '#'"});
}

TEST(AnimationSequence, LoadChecksEveryFrameAndNamesTheMissingOne) {
  AnimationDir dir;
  for (int f = 1; f <= 5; ++f) dir.write(hs::frame_file("vol/smoke_####.vdb", f), "not really a vdb");
  json j = {{"media", {{{"file", "vol/smoke_####.vdb"}, {"density_scale", 2}}}},
            {"render", {{"frames", "1:5"}}}};
  fs::path p = dir.write("s.json", j.dump());
  Scene s = hs::load(p.string());
  // The pattern is resolved against the scene's folder; each frame reads its own file.
  EXPECT_TRUE(fs::path(s.media[0].file).is_absolute());
  EXPECT_TRUE(hs::is_sequence(s.media[0].file));
  Scene f3 = hs::scene_at_frame(s, 3);
  EXPECT_TRUE(fs::equivalent(f3.media[0].file, dir.path() / "vol/smoke_0003.vdb"));
  EXPECT_FLOAT_EQ(f3.media[0].density_scale, 2);

  // Frame 6 is missing: loading with a range that includes it fails, naming the frame and the file.
  std::string msg = expect_error(
      [&] { hs::load(p.string(), {"render.frames=2:8"}); },
      {p.string() + ": media[0].file: frame 6: no such file: ", "smoke_0006.vdb", "frames 2..8"});
  // The same check for another range, as --frames will need it.
  expect_error([&] { hs::check_frame_files(s, 0, 3); },
               {"media[0].file: frame 0: no such file", "smoke_0000.vdb"});
  EXPECT_NO_THROW(hs::check_frame_files(s, 2, 5));
  // Without render.frames and without tracks the range is 0..0, and smoke_0000.vdb is missing.
  fs::path q = dir.write("q.json", json({{"media", {{{"file", "vol/smoke_####.vdb"}}}}}).dump());
  expect_error([&] { hs::load(q.string()); }, {"frame 0: no such file", "smoke_0000.vdb"});
  // The range can come from the keys.
  json k = {{"media", {{{"file", "vol/smoke_####.vdb"}}}},
            {"animation", {{"tracks", {track("media[0].density_scale", {key(1, 1), key(5, 3)})}}}}};
  fs::path r = dir.write("r.json", k.dump());
  Scene rs = hs::load(r.string());
  EXPECT_EQ(hs::frame_range(rs), std::make_pair(1, 5));
  Scene r4 = hs::scene_at_frame(rs, 4);
  EXPECT_TRUE(fs::equivalent(r4.media[0].file, dir.path() / "vol/smoke_0004.vdb"));
  EXPECT_FLOAT_EQ(r4.media[0].density_scale, 2.5f);
}

// ---- errors, each naming its JSON path ----

TEST(AnimationErrors, PathsThatLeadNowhere) {
  auto bad_path = [](const std::string& path, std::initializer_list<std::string> pieces) {
    std::string msg = read_error(animated({track(path, {key(0, 1)})}), pieces);
    EXPECT_NE(msg.find("scene.json: animation.tracks[0].path: "), std::string::npos) << msg;
  };
  bad_path("camera.postion", {"\"camera.postion\"", "did you mean \"position\""});
  bad_path("camra.fov_y", {"did you mean \"camera\""});
  bad_path("media[3].density_scale", {"media has 1 element; there is no media[3]"});
  bad_path("media.x.g", {"media is a list", "\"x\""});
  bad_path("haze.sigma_t", {"haze is not in the scene"});
  bad_path("camera", {"camera is an object"});
  bad_path("media", {"media is a list"});
  bad_path("render.spp", {"render.spp is an integer", "only numbers and [x, y, z]"});
  bad_path("render.seed", {"unsigned integer"});
  bad_path("render.tonemap", {"render.tonemap is a string"});
  bad_path("render.pixel_jitter", {"is a bool"});
  bad_path("render.outputs", {"list of strings"});
  bad_path("media[0].grid", {"media[0].grid is a string"});
  bad_path("media[0].procedural.density", {"media[0].procedural is free-form JSON"});
  bad_path("camera.position.3", {"component 0, 1 or 2"});
  bad_path("camera.fov_y.x", {"camera.fov_y is a number; it has no member \"x\""});
  bad_path("camera.position.1.x", {"camera.position[1] is a number"});
  bad_path("render.fps", {"time base"});
  bad_path("animation.tracks.0.keys.0.frame", {"cannot animate itself"});
  bad_path("camera..position", {"empty part"});
  read_error(animated({{{"keys", {key(0, 1)}}}}), {"animation.tracks[0].path: missing"});
}

TEST(AnimationErrors, Keys) {
  auto at = [](std::vector<json> keys, const std::string& path = "camera.fov_y") {
    return animated({track("camera.position", {key(0, {0, 1, 5})}), track(path, std::move(keys))});
  };
  read_error(at({}), {"scene.json: animation.tracks[1].keys: is empty"});
  read_error(at({key(10, 40), key(5, 50)}),
             {"animation.tracks[1].keys[1].frame", "greater than keys[0].frame (10), got 5"});
  read_error(at({key(10, 40), key(10, 50)}), {"animation.tracks[1].keys[1].frame", "got 10"});
  read_error(at({key(-1, 40)}), {"animation.tracks[1].keys[0].frame", "must be in [0, 9999999], got -1"});
  read_error(at({{{"value", 40}}}), {"animation.tracks[1].keys[0].frame: missing"});
  read_error(at({{{"frame", 3}}}), {"animation.tracks[1].keys[0].value: missing"});
  read_error(at({key(0, 40), {{"frame", 1}, {"value", 50}, {"vaule", 3}}}),
             {"animation.tracks[1].keys[1].vaule", "did you mean \"value\""});
  // Wrong value type for the target.
  read_error(at({key(0, 40), key(1, {1, 2, 3})}), {"animation.tracks[1].keys[1].value", "expected a number"});
  read_error(at({key(0, 2)}, "camera.target"),
             {"animation.tracks[1].keys[0].value", "expected an array of 3 numbers [x, y, z], got 2"});
  read_error(at({key(0, {1, 2})}, "camera.target"), {"animation.tracks[1].keys[0].value", "3 numbers"});
  read_error(at({key(0, "far")}), {"animation.tracks[1].keys[0].value", "expected a number, got \"far\""});
  // The target's range applies to every key.
  read_error(at({key(0, 40), key(5, 180)}), {"animation.tracks[1].keys[1].value", "in (0, 180), got 180"});
  read_error(at({key(0, {0.5, 1.5, 0.5})}, "media[0].albedo"),
             {"animation.tracks[1].keys[0].value[1]", "in [0, 1], got 1.5"});
  read_error(at({key(0, -1)}, "media[0].density_scale"), {"animation.tracks[1].keys[0].value", ">= 0"});
  // Track-level keys.
  json j = at({key(0, 40)});
  j["animation"]["tracks"][1]["interpolation"] = "cubic";
  read_error(j, {"animation.tracks[1].interpolation", "\"linear\", \"smooth\""});
  j["animation"]["tracks"][1]["interpolation"] = "smoth";
  read_error(j, {"animation.tracks[1].interpolation", "did you mean \"smooth\""});
  j["animation"]["tracks"][1].erase("interpolation");
  j["animation"]["tracks"][1]["ease"] = true;
  read_error(j, {"animation.tracks[1].ease: unknown key"});
  read_error({{"animation", {{"track", json::array()}}}}, {"animation.track", "did you mean \"tracks\""});
  read_error({{"animation", {{"tracks", {1}}}}}, {"animation.tracks[0]", "expected an object"});
}

TEST(AnimationErrors, TwoTracksForOneValue) {
  read_error(animated({track("camera.position", {key(0, {0, 1, 5})}),
                       track("camera.position", {key(3, {0, 1, 6})})}),
             {"animation.tracks[1].path", "animation.tracks[0] already animates"});
  read_error(
      animated({track("camera.position", {key(0, {0, 1, 5})}), track("camera.position[1]", {key(3, 1)})}),
      {"animation.tracks[1].path", "camera.position[1]", "animation.tracks[0]"});
  read_error(animated({track("media.0.g", {key(0, 0)}), track("media[0].g", {key(0, 0.5)})}),
             {"animation.tracks[1].path", "media[0].g"});
  // Neighbours are fine.
  EXPECT_NO_THROW(
      read(animated({track("camera.position", {key(0, {0, 1, 5})}), track("camera.fov_y", {key(0, 30)})})));
}

TEST(AnimationErrors, RulesBrokenBetweenKeysNameTheFrame) {
  // A direction through zero halfway.
  std::string msg =
      read_error(animated({track("lights.sun.direction", {key(0, {1, 1, 0}), key(10, {-1, -1, 0})})}),
                 {"scene.json: frame 5: lights.sun.direction: must be a nonzero vector",
                  "(animated by animation.tracks[0])"});
  // Camera target and position meet at frame 5 although both keys are fine.
  read_error(animated({track("camera.position", {key(0, {0, 1, 5}), key(10, {0, 1, -5})})}),
             {"frame 5: camera.target", "animation.tracks[0]"});
  // A scale through zero; the message lists every track that moved the object.
  read_error(animated({track("media[0].transform.scale", {key(0, {1, 1, 1}), key(2, {-1, 1, 1})}),
                       track("media[0].transform.translate", {key(0, {0, 0, 0}), key(2, {1, 1, 1})})}),
             {"frame 1: media[0].transform.scale: components must be nonzero",
              "(animated by animation.tracks[0], animation.tracks[1])"});
  // Only frames in the range are checked on load; scene_at_frame checks the frame it evaluates.
  json j = animated({track("lights.sun.direction", {key(0, {1, 1, 0}), key(10, {-1, -1, 0})})});
  j["render"] = {{"frames", "0:4"}};
  Scene s = read(j);
  EXPECT_NO_THROW(hs::scene_at_frame(s, 4));
  expect_error([&] { hs::scene_at_frame(s, 5); }, {"scene.json: frame 5: lights.sun.direction"});
}

TEST(AnimationErrors, ScenesBuiltInCode) {
  // scene_at_frame checks the tracks itself, for scenes that did not come through from_json.
  Scene s;
  s.animation.emplace();
  s.animation->tracks.push_back({"camera.fov", "linear", {{0, 30}}});
  expect_error([&] { hs::scene_at_frame(s, 0); },
               {"frame 0: animation.tracks[0].path: \"camera.fov\"", "\"fov_y\""});
  s.animation->tracks[0] = {"camera.fov_y", "linear", {}};
  expect_error([&] { hs::scene_at_frame(s, 0); }, {"animation.tracks[0].keys: is empty"});
  s.animation->tracks[0] = {"camera.fov_y", "linear", {{0, 30}, {10, 50}}};
  EXPECT_FLOAT_EQ(hs::scene_at_frame(s, 5).camera.fov_y, 40);
}

TEST(AnimationErrors, RenderFrames) {
  read_error({{"render", {{"frames", "9:3"}}}},
             {"scene.json: render.frames: the first frame (9) is after the last (3)"});
  read_error({{"render", {{"frames", "-2:3"}}}}, {"render.frames", "frames start at 0"});
  read_error({{"render", {{"frames", "a:b"}}}}, {"render.frames", "\"a\""});
  read_error({{"render", {{"frames", 12}}}}, {"render.frames", "expected a string"});
  read_error({{"render", {{"fps", 0}}}}, {"render.fps", "in (0, 1000]"});
}

// ---- --frames ----

TEST(ParseFrames, Accepts) {
  EXPECT_EQ(hs::parse_frames("0:119"), std::make_pair(0, 119));
  EXPECT_EQ(hs::parse_frames("5"), std::make_pair(5, 5));
  EXPECT_EQ(hs::parse_frames("7:7"), std::make_pair(7, 7));
  EXPECT_EQ(hs::parse_frames(" 3 : 8 "), std::make_pair(3, 8));
  EXPECT_EQ(hs::parse_frames("0009:0010"), std::make_pair(9, 10));
  EXPECT_EQ(hs::parse_frames("0:9999999"), std::make_pair(0, hs::kMaxFrame));
}

TEST(ParseFrames, RefusesWithAClearMessage) {
  auto bad = [](const std::string& text, std::initializer_list<std::string> pieces) {
    std::string msg = expect_error([&] { hs::parse_frames(text); }, pieces);
    EXPECT_EQ(msg.rfind("--frames " + text + ": ", 0), 0u) << msg;
  };
  bad("", {"is empty", "A:B"});
  bad("9:3", {"the first frame (9) is after the last (3)", "A <= B"});
  bad("-1:5", {"frames start at 0, got -1"});
  bad("0:-5", {"frames start at 0, got -5"});
  bad(":5", {"a frame number is missing"});
  bad("5:", {"a frame number is missing"});
  bad("a:b", {"expected a frame number, got \"a\""});
  bad("1.5:3", {"got \"1.5\""});
  bad("1:2:3", {"more than one ':'"});
  bad("1-5", {"got \"1-5\""});
  bad("+3", {"got \"+3\""});
  bad("0:10000000", {"too large", "9999999"});
  bad("0:99999999999999999999", {"too large"});
}

// ---- the examples in the docs ----

TEST(AnimationDocs, AnimatedExamplesEvaluateEveryFrame) {
  std::ifstream in(HAZE_SCENE_FORMAT_MD);
  ASSERT_TRUE(in);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string doc = ss.str();
  int animated_examples = 0;
  for (size_t at = doc.find("```json\n"); at != std::string::npos; at = doc.find("```json\n", at)) {
    size_t begin = at + 8, end = doc.find("```", begin);
    ASSERT_NE(end, std::string::npos);
    json j = json::parse(doc.substr(begin, end - begin), nullptr, true, /*ignore_comments=*/true);
    at = end + 3;
    if (!j.contains("animation")) continue;
    ++animated_examples;
    Scene s = hs::from_json(j, "example", "/base");
    auto [first, last] = hs::frame_range(s);
    EXPECT_LT(first, last);
    Scene a = hs::scene_at_frame(s, first), b = hs::scene_at_frame(s, last);
    EXPECT_NE(hs::to_json(a), hs::to_json(b));
  }
  EXPECT_GE(animated_examples, 2);
}
