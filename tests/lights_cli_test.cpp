// Environment maps through the haze binary, as a user meets them: `haze envmap make` writes a sky that a
// scene renders with (its buffers in stats.json), bad output names and bad map files are one-line errors,
// and texels replaced on reading are a `note:` line and a note in stats.json.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "haze_cli.hpp"
#include "lights/environment.hpp"
#include "temp_dir.hpp"

namespace haze::test {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

int lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

// The sky's sun disc lies where --sun-elevation and --sun-azimuth put it, in the orientation
// lights/environment.hpp documents (azimuth 90: towards +x, a quarter of the width right of the centre).
// Injected defect caught (measured): the sun's azimuth mirrored in make_sky (column 16 instead of 48).
TEST(EnvmapCli, MakeWritesTheSkyWhereTheSunIs) {
  TempDir dir("haze_lights_cli");
  const std::string out = (dir.path() / "sky.exr").string();
  Result r =
      run(fmt::format("envmap make --out {} --width 64 --height 32 --sun-elevation 30 --sun-azimuth 90 "
                      "--sun-size 6",
                      out));
  ASSERT_EQ(r.code, 0) << r.out;
  const lights::EnvironmentMap m = lights::read_environment_map(out);
  ASSERT_EQ(m.width, 64u);
  ASSERT_EQ(m.height, 32u);
  size_t best = 0;
  for (size_t k = 0; k < m.texels.size(); ++k)
    if (m.texels[k].g > m.texels[best].g) best = k;
  // Elevation 30: theta 60 degrees, v = 1/3 (row 10.67); azimuth 90: u = 3/4 (column 48).
  EXPECT_NEAR(double(best % 64) + 0.5, 48.0, 1.0);
  EXPECT_NEAR(double(best / 64) + 0.5, 32.0 / 3.0, 1.0);
  EXPECT_GT(m.texels[best].g, 100.f);

  // An output that is neither .exr nor .hdr: one line, non-zero, nothing written (no temporary left).
  const std::string png = (dir.path() / "sky.png").string();
  r = run(fmt::format("envmap make --out {}", png));
  EXPECT_NE(r.code, 0);
  EXPECT_EQ(lines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find("name an .exr or .hdr file"), std::string::npos) << r.out;
  int files = 0;
  for (const auto& e : fs::directory_iterator(dir.path())) files += e.path().filename() != "sky.exr";
  EXPECT_EQ(files, 0);
}

// Injected defect caught (measured): the map not checked before the device starts (the error came second,
// after the device line).
TEST(EnvmapCli, ScenesRenderWithAMapAndReportBadOnes) {
  TempDir dir("haze_lights_cli");
  ASSERT_EQ(
      run(fmt::format("envmap make --out {} --width 32 --height 16", (dir.path() / "sky.hdr").string())).code,
      0);
  const json scene = {
      {"camera", {{"position", {0, 1, 3}}, {"target", {0, 1, 0}}}},
      {"haze", {{"sigma_t", 0.2}, {"bounded", true}, {"bounds_min", {-1, 0, -1}}, {"bounds_max", {1, 2, 1}}}},
      {"lights", {{"environment", {{"file", "sky.hdr"}, {"rotate", 45}}}}},
      {"render", {{"width", 8}, {"height", 6}, {"spp", 2}}}};
  const std::string s = dir.write("s.json", scene.dump()).string();
  Result r = run(fmt::format("render {} --out {}", s, (dir.path() / "out").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  std::ifstream in(dir.path() / "out" / "stats.json");
  const json stats = json::parse(in);
  int env_buffers = 0;
  for (const auto& e : stats["memory"]["entries"])
    env_buffers += e["name"].get<std::string>().rfind("environment ", 0) == 0;
  EXPECT_EQ(env_buffers, 3);
  EXPECT_NE(stats["features"].get<std::string>().find("env_map"), std::string::npos) << stats["features"];

  // Texels with NaN: a note on the terminal and in stats.json.
  lights::EnvironmentMap m = lights::read_environment_map((dir.path() / "sky.hdr").string());
  m.texels[3] = glm::vec3(NAN, 1, 1);
  lights::write_environment_map((dir.path() / "nan.exr").string(), m);
  json with_nan = scene;
  with_nan["lights"]["environment"]["file"] = "nan.exr";
  r = run(fmt::format("render {} --out {}", dir.write("n.json", with_nan.dump()).string(),
                      (dir.path() / "out_nan").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("note: lights.environment.file"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("1 texel channels replaced by 0 (1 NaN"), std::string::npos) << r.out;
  std::ifstream in2(dir.path() / "out_nan" / "stats.json");
  EXPECT_NE(json::parse(in2)["notes"].dump().find("NaN"), std::string::npos);

  // A file that is not an image: one line naming the key and the file, non-zero, no output folder.
  dir.write("junk.exr", "not an image");
  json junk = scene;
  junk["lights"]["environment"]["file"] = "junk.exr";
  r = run(fmt::format("render {} --out {}", dir.write("j.json", junk.dump()).string(),
                      (dir.path() / "out_junk").string()));
  EXPECT_NE(r.code, 0);
  EXPECT_EQ(lines(r.out), 1) << r.out;
  EXPECT_NE(r.out.find("lights.environment.file"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("junk.exr"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(dir.path() / "out_junk" / "stats.json"));
}

}  // namespace
}  // namespace haze::test
