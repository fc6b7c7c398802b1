#include "scene/scene.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <glm/vec4.hpp>
#include <initializer_list>
#include <set>
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

json procedural_medium() {
  return {{"procedural", {{"kind", "cloud"}, {"seed", 3}}}};
}

// A scene that uses every feature, for round trips.
json full_scene() {
  return json::parse(R"({
    "camera": {"position": [1, 2, 3], "target": [0, 0.5, 0], "up": [0, 0, 1], "fov_y": 30},
    "media": [
      {"file": "/data/smoke.vdb", "density_scale": 2.5, "albedo": [0.8, 0.7, 0.6], "g": 0.3,
       "emission": {"mode": "blackbody", "grid": "temperature", "scale": 2, "temperature_scale": 1500},
       "transform": {"translate": [1, 0, 0], "rotate": [0, 90, 0], "scale": [2, 2, 2]}},
      {"procedural": {"kind": "sphere", "center": [0, 1, 0], "size": [1, 1, 1], "density": 4}}
    ],
    "haze": {"sigma_t": 0.1, "bounded": true, "bounds_min": [-5, 0, -5], "bounds_max": [5, 3, 5]},
    "lights": {
      "sun": {"direction": [0, 2, 0], "irradiance": 3, "color": [1, 0.9, 0.8]},
      "points": [{"position": [0, 2, 0], "intensity": 50}],
      "spots": [{"position": [0, 4, 0], "direction": [0, -1, 0], "cone_angle": 20, "falloff_angle": 4}],
      "environment": {"color": [0.1, 0.2, 0.4], "intensity": 0.5}
    },
    "render": {"width": 64, "height": 32, "spp": 4, "max_depth": 3, "seed": 4000000000,
               "tonemap": "reinhard", "outputs": ["exr"], "exposure": -1.5}
  })");
}

// Each test's files live in its own folder.
struct SceneDir : haze::test::TempDir {
  SceneDir() : haze::test::TempDir("haze_scene_test") {}
};

}  // namespace

// ---- defaults and round trips ----

TEST(SceneJson, DefaultsRoundTrip) {
  json a = hs::to_json(Scene{});
  json b = hs::to_json(hs::from_json(a, "defaults", ""));
  EXPECT_EQ(a, b) << a.dump(2) << "\n" << b.dump(2);
  // Floats are written as their shortest text, not as widened doubles.
  EXPECT_EQ(a["render"]["outputs"], json({"exr", "png", "stats"}));
  EXPECT_EQ(a["camera"]["fov_y"].dump(), "45.0");
  EXPECT_FALSE(a.contains("haze"));  // absent optional sections stay absent
  EXPECT_FALSE(a["lights"].contains("sun"));
}

TEST(SceneJson, EmptyObjectGivesDefaults) {
  Scene s = hs::from_json(json::object(), "scene.json", "");
  EXPECT_EQ(s.render.width, 320);
  EXPECT_EQ(s.render.height, 180);
  EXPECT_EQ(s.render.spp, 16);
  EXPECT_EQ(s.render.tonemap, "aces");
  EXPECT_EQ(s.camera.position, glm::vec3(0, 1, 5));
  EXPECT_TRUE(s.media.empty());
  EXPECT_FALSE(s.haze);
  EXPECT_FALSE(s.lights.sun);
  EXPECT_EQ(s.path, "scene.json");
}

TEST(SceneJson, FullSceneRoundTrip) {
  Scene s = hs::from_json(full_scene(), "full.json", "");
  ASSERT_EQ(s.media.size(), 2u);
  EXPECT_EQ(s.media[0].emission.mode, "blackbody");
  EXPECT_FLOAT_EQ(s.media[0].density_scale, 2.5f);
  ASSERT_TRUE(s.media[1].procedural);
  EXPECT_EQ((*s.media[1].procedural)["kind"], "sphere");
  ASSERT_TRUE(s.haze);
  EXPECT_TRUE(s.haze->bounded);
  EXPECT_FLOAT_EQ(s.haze->albedo.x, 0.9f);  // partial object: the rest keeps defaults
  ASSERT_TRUE(s.lights.sun);
  EXPECT_EQ(s.lights.sun->direction, glm::vec3(0, 1, 0));  // normalised on load
  EXPECT_EQ(s.render.seed, 4000000000u);
  EXPECT_TRUE(s.render.wants("exr"));
  EXPECT_FALSE(s.render.wants("png"));

  json a = hs::to_json(s);
  json b = hs::to_json(hs::from_json(a, "again", ""));
  EXPECT_EQ(a, b);
  EXPECT_EQ(a["render"]["exposure"], -1.5);
  EXPECT_EQ(a["media"][0]["albedo"], json({0.8, 0.7, 0.6}));
}

TEST(SceneJson, IntegersWrittenAsFloatsAreAccepted) {
  Scene s = hs::from_json({{"render", {{"spp", 64.0}, {"width", 1e3}}}}, "scene.json", "");
  EXPECT_EQ(s.render.spp, 64);
  EXPECT_EQ(s.render.width, 1000);
}

// ---- errors while reading ----

TEST(SceneErrors, RangeMessagesNameTheJsonPath) {
  json j = {{"media", {procedural_medium(), procedural_medium()}}};
  j["media"][1]["density_scale"] = -2;
  std::string msg = read_error(j, {});
  EXPECT_EQ(msg, "scene.json: media[1].density_scale: must be >= 0, got -2");

  read_error({{"render", {{"spp", 0}}}}, {"scene.json: render.spp: must be in [1, 1048576], got 0"});
  read_error({{"render", {{"width", 20000}}}}, {"render.width", "in [1, 16384]"});
  read_error({{"camera", {{"fov_y", 180}}}}, {"camera.fov_y", "in (0, 180)", "got 180"});
  j = {{"media", {procedural_medium()}}};
  j["media"][0]["albedo"] = {0.5, 1.2, 0.3};
  read_error(j, {"media[0].albedo[1]", "must be in [0, 1], got 1.2"});
  j["media"][0]["albedo"] = {0.5, 0.5, 0.5};
  j["media"][0]["g"] = -1.5;
  read_error(j, {"media[0].g", "[-1, 1]"});
  read_error({{"lights", {{"spots", {{{"cone_angle", 0}}}}}}}, {"lights.spots[0].cone_angle", "in (0, 90]"});
  read_error({{"render", {{"seed", -1}}}}, {"render.seed", "got -1"});
  read_error({{"render", {{"seed", 4294967296LL}}}}, {"render.seed", "4294967295"});
  read_error({{"haze", {{"sigma_t", 1e39}}}}, {"haze.sigma_t", "32-bit float"});
  j = {{"media", {procedural_medium()}}};
  j["media"][0]["bounds_min"] = {0, 0, 0};
  j["media"][0]["bounds_max"] = {1, 0, 1};
  read_error(j, {"scene.json: media[0].bounds_max", "greater than bounds_min"});
}

TEST(SceneErrors, WrongTypes) {
  read_error({{"render", {{"width", "big"}}}}, {"render.width", "expected an integer", "\"big\""});
  read_error({{"render", {{"width", 2.5}}}}, {"render.width", "expected an integer, got 2.5"});
  read_error({{"render", {{"exposure", true}}}}, {"render.exposure", "expected a number"});
  read_error({{"haze", {{"bounded", 1}}}}, {"haze.bounded", "expected true or false"});
  read_error({{"camera", {{"position", {1, 2}}}}},
             {"camera.position", "3 numbers", "an array of 2 elements"});
  read_error({{"camera", {{"position", {1, "a", 2}}}}}, {"camera.position[1]", "expected a number"});
  read_error({{"camera", 3}}, {"scene.json: camera: expected an object"});
  read_error({{"media", {{"file", "x.vdb"}}}}, {"media", "expected an array of objects"});
  read_error({{"render", {{"outputs", "exr"}}}}, {"render.outputs", "array of strings"});
  read_error(json::array(), {"scene.json: (top level): expected an object"});
}

TEST(SceneErrors, UnknownKeysSuggestTheNearestName) {
  std::string msg = read_error({{"render", {{"sppp", 3}}}}, {});
  EXPECT_EQ(msg, "scene.json: render.sppp: unknown key (did you mean \"spp\"?)");
  read_error({{"camera", {{"fvo_y", 3}}}}, {"camera.fvo_y", "did you mean \"fov_y\""});
  read_error({{"lights", {{"sun", {{"Irradiance", 3}}}}}}, {"lights.sun.Irradiance", "\"irradiance\""});
  // Nothing close: list the valid keys instead.
  read_error({{"render", {{"quality", "high"}}}},
             {"render.quality", "expected one of", "\"spp\"", "\"tonemap\""});
  read_error({{"camrea", json::object()}}, {"scene.json: camrea: unknown key (did you mean \"camera\"?)"});
  json j = {{"media", {procedural_medium()}}};
  j["media"][0]["densty_scale"] = 1;
  read_error(j, {"media[0].densty_scale", "\"density_scale\""});
}

TEST(SceneErrors, Choices) {
  read_error({{"render", {{"tonemap", "reinhart"}}}},
             {"render.tonemap", "one of \"aces\", \"reinhard\", \"clamp\"", "did you mean \"reinhard\""});
  read_error({{"render", {{"outputs", {"exr", "jpg"}}}}}, {"render.outputs[1]", "\"jpg\""});
  read_error({{"render", {{"outputs", {"exr", "exr"}}}}}, {"render.outputs[1]", "listed twice"});
  json j = {{"media", {procedural_medium()}}};
  j["media"][0]["emission"] = {{"mode", "flame"}};
  read_error(j, {"media[0].emission.mode", "blackbody"});
}

TEST(SceneErrors, DegenerateGeometry) {
  read_error({{"camera", {{"position", {0, 1, 0}}, {"target", {0, 1, 0}}}}},
             {"camera.target", "camera.position"});
  read_error({{"camera", {{"position", {0, 5, 0}}, {"target", {0, 0, 0}}}}}, {"camera.up", "parallel"});
  read_error({{"camera", {{"up", {0, 0, 0}}}}}, {"camera.up", "nonzero"});
  read_error({{"lights", {{"sun", {{"direction", {0, 0, 0}}}}}}}, {"lights.sun.direction", "nonzero"});
  read_error({{"lights", {{"spots", {{{"direction", {0, 0, 0}}}}}}}},
             {"lights.spots[0].direction", "nonzero"});
  read_error({{"lights", {{"spots", {{{"cone_angle", 10}, {"falloff_angle", 20}}}}}}},
             {"lights.spots[0].falloff_angle", "cone_angle"});
  read_error({{"haze", {{"bounded", true}, {"bounds_min", {0, 0, 0}}, {"bounds_max", {1, 0, 1}}}}},
             {"haze.bounds_max", "greater than bounds_min"});
  json j = {{"media", {procedural_medium()}}};
  j["media"][0]["transform"] = {{"scale", {1, 0, 1}}};
  read_error(j, {"media[0].transform.scale", "nonzero"});
}

TEST(SceneErrors, MediumNeedsExactlyOneSource) {
  read_error({{"media", {json::object()}}}, {"scene.json: media[0]:", "\"file\"", "\"procedural\""});
  json both = procedural_medium();
  both["file"] = "a.vdb";
  read_error({{"media", {both}}}, {"media[0].procedural", "exactly one"});
  read_error({{"media", {{{"procedural", 3}}}}}, {"media[0].procedural", "expected an object"});
  read_error({{"media", {{{"procedural", {{"size", 1}}}}}}}, {"media[0].procedural.kind", "cloud"});
  // null means absent.
  read_error({{"media", {{{"procedural", nullptr}}}}}, {"media[0]:", "needs"});
  // A procedural medium has no other grid to name (they used to mean "density" silently).
  json named = procedural_medium();
  named["grid"] = "smoke";
  read_error({{"media", {named}}}, {"scene.json: media[0].grid", "\"smoke\"", "one grid, \"density\""});
  json emitting = procedural_medium();
  emitting["emission"] = {{"mode", "scale"}, {"grid", "temperature"}};
  read_error({{"media", {emitting}}},
             {"scene.json: media[0].emission.grid", "\"temperature\"", "driven by its density"});
  emitting["emission"]["grid"] = "density";
  EXPECT_EQ(hs::from_json({{"media", {emitting}}}, "scene.json", "").media[0].emission.grid, "density");
  emitting["emission"].erase("grid");
  EXPECT_EQ(hs::from_json({{"media", {emitting}}}, "scene.json", "").media[0].emission.grid, "density");
}

TEST(SceneErrors, NullSwitchesOptionalSectionsOff) {
  Scene s = hs::from_json({{"haze", nullptr}, {"lights", {{"sun", nullptr}}}}, "scene.json", "");
  EXPECT_FALSE(s.haze);
  EXPECT_FALSE(s.lights.sun);
  read_error({{"render", {{"spp", nullptr}}}}, {"render.spp", "expected an integer, got null"});
}

// ---- files ----

TEST(SceneLoad, MissingFile) {
  std::string msg = expect_error([] { hs::load("/nonexistent/dir/scene.json"); },
                                 {"cannot open scene file /nonexistent/dir/scene.json: "});
  EXPECT_EQ(msg.rfind("cannot open scene file", 0), 0u);
  SceneDir dir;
  expect_error([&] { hs::load(dir.path().string()); }, {"cannot open scene file", "directory"});
}

TEST(SceneLoad, MalformedJsonGivesLineAndColumn) {
  SceneDir dir;
  fs::path p = dir.write("bad.json", "{\n  \"render\": {\n    \"spp\": 4,,\n  }\n}\n");
  expect_error([&] { hs::load(p.string()); },
               {p.string() + ": line 3, column 14: malformed JSON", "fix the syntax"});
  fs::path empty = dir.write("empty.json", "");
  expect_error([&] { hs::load(empty.string()); }, {empty.string() + ": line 1, column 1: malformed JSON"});
}

// nlohmann::json keeps the last of two equal keys without a word; a scene file with one is refused.
TEST(SceneLoad, DuplicateKeysAreNamed) {
  SceneDir dir;
  fs::path p = dir.write("dup.json", "{\"render\": {\"spp\": 4, \"width\": 8, \"spp\": 16}}");
  expect_error([&] { hs::load(p.string()); },
               {p.string() + ": render.spp: the key appears twice", "keep one"});
  fs::path q =
      dir.write("dup2.json", "{\"media\": [{\"file\": \"a.vdb\"}, {\"grid\": \"d\", \"grid\": \"e\"}]}");
  expect_error([&] { hs::load(q.string()); }, {"media[1].grid: the key appears twice"});
  EXPECT_EQ(haze::reflection::duplicate_key("{\"a\": {\"b\": 1}, \"c\": [{\"b\": 2}, {\"b\": 3}]} // ok"),
            "");
  EXPECT_EQ(haze::reflection::duplicate_key("[1, {\"x\": [{}, {\"y\": 1, \"y\": 2}]}]"), "[1].x[1].y");
}

TEST(SceneLoad, CommentsAreAllowed) {
  SceneDir dir;
  fs::path p = dir.write("c.json", "// a comment\n{ /* spp */ \"render\": {\"spp\": 8} }\n");
  EXPECT_EQ(hs::load(p.string()).render.spp, 8);
}

TEST(SceneLoad, RelativeMediaFilesResolveAgainstTheSceneFolder) {
  SceneDir dir;
  dir.write("volumes/cloud.vdb", "not really a vdb");
  fs::path p =
      dir.write("scenes/a.json", R"({"media": [{"file": "../volumes/cloud.vdb"}, {"file": "/abs/x.vdb"}]})");
  // from_json resolves without checking existence.
  json j = json::parse(std::ifstream(p));
  Scene m = hs::from_json(j, p.string(), "/base");
  EXPECT_EQ(m.media[0].file, "/volumes/cloud.vdb");
  EXPECT_EQ(m.media[1].file, "/abs/x.vdb");
  EXPECT_EQ(m.base_dir, "/base");

  // load resolves against the file's folder and checks existence.
  expect_error([&] { hs::load(p.string()); }, {p.string() + ": media[1].file: no such file: /abs/x.vdb"});
  dir.write("scenes/b.json", R"({"media": [{"file": "../volumes/cloud.vdb", "density_scale": 3}]})");
  Scene s = hs::load((dir.path() / "scenes/b.json").string());
  ASSERT_EQ(s.media.size(), 1u);
  EXPECT_TRUE(fs::path(s.media[0].file).is_absolute());
  EXPECT_TRUE(fs::equivalent(s.media[0].file, dir.path() / "volumes/cloud.vdb"));
  EXPECT_TRUE(fs::equivalent(s.base_dir, dir.path() / "scenes"));
  EXPECT_EQ(s.path, (dir.path() / "scenes/b.json").string());
  // Written paths are absolute, so stats.json can be read back from anywhere.
  Scene again = hs::from_json(hs::to_json(s), "stats.json", "/elsewhere");
  EXPECT_EQ(again.media[0].file, s.media[0].file);
}

// ---- overrides ----

TEST(SceneOverrides, SetNestedValues) {
  json j = {{"media", {procedural_medium(), {{"file", "a.vdb"}}}}, {"camera", {{"position", {0, 1, 5}}}}};
  hs::apply_override(j, "render.spp=64", "scene.json");
  hs::apply_override(j, "media.0.density_scale=2", "scene.json");
  hs::apply_override(j, "media[0].albedo=[0.5, 0.6, 0.7]", "scene.json");
  hs::apply_override(j, "lights.sun.irradiance=3", "scene.json");  // creates the sun
  hs::apply_override(j, "camera.position.1=7", "scene.json");
  hs::apply_override(j, "camera.target=0,2,0", "scene.json");
  hs::apply_override(j, "render.tonemap=reinhard", "scene.json");
  hs::apply_override(j, "render.outputs=exr,stats", "scene.json");
  hs::apply_override(j, "media.1.grid=123", "scene.json");  // strings need no quotes
  hs::apply_override(j, "media.0.procedural.seed=9", "scene.json");
  hs::apply_override(j, "media.1.emission={\"mode\": \"scale\", \"grid\": \"heat\"}", "scene.json");
  hs::apply_override(j, "haze.sigma_t = 0.2", "scene.json");
  Scene s = hs::from_json(j, "scene.json", "");
  EXPECT_EQ(s.render.spp, 64);
  EXPECT_FLOAT_EQ(s.media[0].density_scale, 2.f);
  EXPECT_EQ(s.media[0].albedo, glm::vec3(0.5f, 0.6f, 0.7f));
  ASSERT_TRUE(s.lights.sun);
  EXPECT_FLOAT_EQ(s.lights.sun->irradiance, 3.f);
  EXPECT_EQ(s.camera.position, glm::vec3(0, 7, 5));
  EXPECT_EQ(s.camera.target, glm::vec3(0, 2, 0));
  EXPECT_EQ(s.render.tonemap, "reinhard");
  EXPECT_EQ(s.render.outputs, (std::vector<std::string>{"exr", "stats"}));
  EXPECT_EQ(s.media[1].grid, "123");
  EXPECT_EQ((*s.media[0].procedural)["seed"], 9);
  EXPECT_EQ(s.media[1].emission.mode, "scale");
  EXPECT_EQ(s.media[1].emission.grid, "heat");
  ASSERT_TRUE(s.haze);
  EXPECT_FLOAT_EQ(s.haze->sigma_t, 0.2f);

  hs::apply_override(j, "haze=null", "scene.json");
  EXPECT_FALSE(hs::from_json(j, "scene.json", "").haze);
}

TEST(SceneOverrides, Errors) {
  json j = {{"media", {procedural_medium(), procedural_medium()}}};
  auto set = [&](const std::string& a) { return [&j, a] { hs::apply_override(j, a, "scene.json"); }; };
  hs::apply_override(j, "media[1].g=0.25", "scene.json");  // both spellings of an index
  hs::apply_override(j, "media.0.g=0.5", "scene.json");
  EXPECT_EQ(j["media"][1]["g"], 0.25);
  EXPECT_EQ(j["media"][0]["g"], 0.5);
  expect_error(set("render.sppp=3"),
               {"scene.json: render.sppp: unknown key (did you mean \"spp\"?)", "--set"});
  expect_error(set("rendr.spp=3"), {"rendr", "did you mean \"render\""});
  expect_error(set("media.3.g=0.5"), {"media[3]", "no such element", "media has 2"});
  expect_error(set("lights.points.0.intensity=1"), {"lights.points", "no element 0"});
  expect_error(set("media.x.g=0.5"), {"media", "index", "\"x\""});
  expect_error(set("camera.position.3=1"), {"camera.position", "0..2"});
  expect_error(set("render.spp.x=1"), {"render.spp", "no member \"x\""});
  expect_error(set("render.exposure=nan"), {"render.exposure", "finite"});
  expect_error(set("render.exposure=-inf"), {"render.exposure", "finite"});
  expect_error(set("render.spp=lots"), {"render.spp", "expected a number"});
  expect_error(set("camera.position=1,nan,2"), {"camera.position", "finite"});
  expect_error(set("render.spp"), {"expected dotted.path=value"});
  expect_error(set("render..spp=1"), {"empty part"});
  // Brackets are an index after a key, nothing else.
  expect_error(set("media[0.g=0.5"), {"media[0.g", "a '[' without its index and ']'"});
  expect_error(set("media[0]].g=0.5"), {"media[0]].g", "a ']' must be followed by"});
  expect_error(set("media]0.g=0.5"), {"a ']' without its '['"});
  expect_error(set("[0].g=0.5"), {"an index [n] must follow a key"});
  expect_error(set("media[0]g=0.5"), {"a ']' must be followed by"});
  expect_error(set("media.=1"), {"empty part"});
  expect_error(set("camera.position.1=7"), {"camera.position", "not in the file"});  // no such array in j
  // Values that parse as JSON but are out of range are caught by the reader, which names the --set.
  SceneDir dir;
  fs::path p = dir.write("s.json", "{}");
  expect_error([&] { hs::load(p.string(), {"render.spp=0"}); },
               {p.string() + ": render.spp: must be in [1, 1048576], got 0", "--set render.spp=0"});
  expect_error([&] { hs::load(p.string(), {"render.exposure=1e999"}); }, {"render.exposure", "finite"});
  expect_error([&] { hs::load(p.string(), {"lights.sun.direction=[0,0,0]"}); },
               {"lights.sun.direction", "nonzero", "--set lights.sun.direction=[0,0,0]"});
  // The last override of a key is the one whose value is read, and the one an error names.
  const std::string msg = expect_error(
      [&] {
        hs::load(p.string(), {"render.spp=5", "render.spp=0"});
      },
      {"got 0", "(value from --set render.spp=0)"});
  EXPECT_EQ(msg.find("render.spp=5"), std::string::npos) << msg;
  Scene s = hs::load(p.string(), {"render.spp=5", "render.width=10"});
  EXPECT_EQ(s.render.spp, 5);
  EXPECT_EQ(s.render.width, 10);
}

// ---- describe, docs ----

TEST(SceneDescribe, ListsEveryPath) {
  auto params = hs::describe();
  auto find = [&](const std::string& path) -> const hs::ParamInfo* {
    for (const auto& p : params)
      if (p.path == path) return &p;
    return nullptr;
  };
  const hs::ParamInfo* spp = find("render.spp");
  ASSERT_TRUE(spp);
  EXPECT_EQ(spp->default_value, "16");
  EXPECT_EQ(spp->constraint, "in [1, 1048576]");
  EXPECT_EQ(spp->type, "integer");
  ASSERT_TRUE(find("media[].albedo"));
  EXPECT_EQ(find("media[].albedo")->constraint, "in [0, 1]");
  ASSERT_TRUE(find("media[].emission.temperature_scale"));
  ASSERT_TRUE(find("lights.sun.irradiance"));
  EXPECT_EQ(find("lights.sun")->default_value, "absent");
  EXPECT_EQ(find("render.tonemap")->constraint, "one of \"aces\", \"reinhard\", \"clamp\"");
  std::string text = hs::format_params(params);
  EXPECT_NE(text.find("render.spp"), std::string::npos);
}

TEST(SceneDescribe, DocsMentionEveryParameter) {
  std::ifstream in(HAZE_SCENE_FORMAT_MD);
  ASSERT_TRUE(in) << "cannot open " << HAZE_SCENE_FORMAT_MD;
  std::stringstream ss;
  ss << in.rdbuf();
  std::string doc = ss.str();
  for (const auto& p : hs::describe()) {
    EXPECT_NE(doc.find("`" + p.path + "`"), std::string::npos) << p.path << " is not documented";
  }
}

// The rule that lists the file's sections names every top-level key the scene has, and says how many.
TEST(SceneDocs, SectionListIsComplete) {
  std::ifstream in(HAZE_SCENE_FORMAT_MD);
  ASSERT_TRUE(in);
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string doc = ss.str();
  const size_t at = doc.find("The file holds one object with up to ");
  ASSERT_NE(at, std::string::npos);
  const std::string rule = doc.substr(at, doc.find('.', at) - at);
  std::set<std::string> sections;
  for (const auto& p : hs::describe()) sections.insert(p.path.substr(0, p.path.find_first_of(".[")));
  for (const auto& s : sections) EXPECT_NE(rule.find("`" + s + "`"), std::string::npos) << s << ": " << rule;
  const char* words[] = {"zero",  "one",   "two",  "three", "four",   "five",  "six",
                         "seven", "eight", "nine", "ten",   "eleven", "twelve"};
  ASSERT_LT(sections.size(), std::size(words));
  EXPECT_NE(rule.find(std::string("up to ") + words[sections.size()] + " sections"), std::string::npos)
      << rule;
}

TEST(SceneDocs, ExamplesLoad) {
  std::ifstream in(HAZE_SCENE_FORMAT_MD);
  ASSERT_TRUE(in);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string doc = ss.str();
  int examples = 0;
  for (size_t at = doc.find("```json\n"); at != std::string::npos; at = doc.find("```json\n", at)) {
    size_t begin = at + 8, end = doc.find("```", begin);
    ASSERT_NE(end, std::string::npos);
    std::string label = "scene-format.md example " + std::to_string(++examples);
    json j = json::parse(doc.substr(begin, end - begin), nullptr, true, /*ignore_comments=*/true);
    EXPECT_NO_THROW(hs::from_json(j, label, "/base")) << label;
    at = end + 3;
  }
  EXPECT_GE(examples, 8);
}

// ---- the reflection works for any struct, not only the scene ----

namespace demo {
struct Inner {
  double weight = 0.5;
};
struct Params {
  bool enabled = true;
  double sigma = 1.0;
  std::optional<Inner> inner;
};
template <class V>
void reflect(V& v, Inner& i) {
  v.field("weight", i.weight, hs::Range{0, 1}, "a weight");
}
template <class V>
void reflect(V& v, Params& p) {
  v.field("enabled", p.enabled, "on/off");
  v.field("sigma", p.sigma, hs::Range::above(0), "a width");
  v.field("inner", p.inner, "optional part");
}
}  // namespace demo

TEST(Reflection, WorksForOtherStructs) {
  demo::Params p;
  hs::ReadContext ctx{"denoise.json", {}};
  haze::reflection::read_params(json{{"sigma", 2.0}, {"inner", {{"weight", 0.25}}}}, p, ctx,
                                "denoise.volume");
  EXPECT_DOUBLE_EQ(p.sigma, 2.0);
  ASSERT_TRUE(p.inner);
  EXPECT_DOUBLE_EQ(p.inner->weight, 0.25);
  EXPECT_EQ(haze::reflection::write_params(p),
            (json{{"enabled", true}, {"sigma", 2.0}, {"inner", {{"weight", 0.25}}}}));
  expect_error(
      [&] {
        haze::reflection::read_params(json{{"sigma", 0}}, p, ctx, "denoise.volume");
      },
      {"denoise.json: denoise.volume.sigma: must be > 0, got 0"});
  json j;
  EXPECT_EQ(haze::reflection::apply_override_to<demo::Params>(j, "inner.weight=0.75", "cli"), "inner.weight");
  EXPECT_EQ(j, (json{{"inner", {{"weight", 0.75}}}}));
}

TEST(Transform, MatrixAppliesScaleThenRotationThenTranslation) {
  hs::Transform t;
  t.translate = {10, 0, 0};
  t.rotate = {0, 0, 90};
  t.scale = {2, 2, 2};
  glm::vec4 p = t.matrix() * glm::vec4(1, 0, 0, 1);
  EXPECT_NEAR(p.x, 10, 1e-5);
  EXPECT_NEAR(p.y, 2, 1e-5);
  EXPECT_NEAR(p.z, 0, 1e-5);
  // x first, then y: (0,1,0) -rx90-> (0,0,1) -ry90-> (1,0,0).
  hs::Transform r;
  r.rotate = {90, 90, 0};
  glm::vec4 q = r.matrix() * glm::vec4(0, 1, 0, 0);
  EXPECT_NEAR(q.x, 1, 1e-5);
  EXPECT_NEAR(q.y, 0, 1e-5);
  EXPECT_NEAR(q.z, 0, 1e-5);
}
