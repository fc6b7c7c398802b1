// The haze command as a user runs it: outputs, determinism, and bad input (one-line error naming the file
// or key, non-zero exit, nothing already written lost).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <stb/stb_image.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "haze_cli.hpp"
#include "render/output.hpp"

namespace {

namespace fs = std::filesystem;

using haze::test::Result;
using haze::test::run;

class Cli : public ::testing::Test {
 protected:
  fs::path dir;
  void SetUp() override {
    dir = fs::temp_directory_path() /
          fmt::format("haze-cli-{}-{}", ::testing::UnitTest::GetInstance()->current_test_info()->name(),
                      getpid());
    fs::remove_all(dir);
    fs::create_directories(dir);
  }
  void TearDown() override { fs::remove_all(dir); }
  std::string write(const std::string& name, const std::string& text) {
    fs::path p = dir / name;
    std::ofstream(p) << text;
    return p.string();
  }
  // A quick scene: homogeneous haze and a sun (no PNanoVDB in the shader variant).
  std::string small_scene(const std::string& extra_render = "") {
    return write("scene.json", fmt::format(R"({{
      "camera": {{"position": [0, 1, 5], "target": [0, 1, 0]}},
      "haze": {{"sigma_t": 0.3, "bounded": true, "bounds_min": [-2, -2, -2], "bounds_max": [2, 2, 2]}},
      "lights": {{"sun": {{"direction": [0.3, 1, 0.2]}}}},
      "render": {{"width": 24, "height": 16, "spp": 4 {}}}
    }})",
                                           extra_render));
  }
};

void expect_one_line_error(const Result& r, const std::string& needle) {
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_NE(r.out.find(needle), std::string::npos) << "expected '" << needle << "' in: " << r.out;
  EXPECT_NE(r.out.find("haze: error: "), std::string::npos) << r.out;
  // The error itself is one line.
  auto pos = r.out.find("haze: error: ");
  if (pos != std::string::npos) {
    std::string rest = r.out.substr(pos);
    EXPECT_EQ(rest.find('\n'), rest.size() - 1) << r.out;
  }
}

std::string file_bytes(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

// No temporary of this or a killed run is left in `d`.
void expect_no_temporaries(const fs::path& d) {
  for (const auto& e : fs::directory_iterator(d))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
}

// Permutations are compiled on demand into the --shader-cache folder: the first run compiles, the second
// takes every kernel from the cache; an unusable folder is one warning, never a failure.
TEST_F(Cli, ShaderCacheCompilesOnceThenHits) {
  const std::string scene = small_scene(), cache = (dir / "shaders").string();
  auto shaders = [&](const fs::path& out) {
    return nlohmann::json::parse(std::ifstream(out / "stats.json"))["shaders"];
  };
  auto r = run(fmt::format("render {} --out {} --shader-cache {}", scene, (dir / "a").string(), cache));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto first = shaders(dir / "a");
  EXPECT_GE(first["compiled"].get<int>(), 1) << first;
  EXPECT_GT(first["compile_ms"].get<double>(), 0.0) << first;
  r = run(fmt::format("render {} --out {} --shader-cache {}", scene, (dir / "b").string(), cache));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto second = shaders(dir / "b");
  EXPECT_EQ(second["compiled"].get<int>(), 0) << second;
  EXPECT_GE(second["cache_hits"].get<int>(), 1) << second;
  EXPECT_EQ(second["cache_hits"].get<int>(), first["compiled"].get<int>() + first["cache_hits"].get<int>());
  // The same images either way.
  for (const char* f : {"frame_0000.exr", "frame_0000.png"}) {
    std::ifstream a(dir / "a" / f, std::ios::binary), b(dir / "b" / f, std::ios::binary);
    EXPECT_TRUE(std::equal(std::istreambuf_iterator<char>(a), {}, std::istreambuf_iterator<char>(b), {}))
        << f;
  }
  // HAZE_SHADER_CACHE names the folder too.
  const char* saved = std::getenv("HAZE_SHADER_CACHE");
  const std::string saved_value = saved ? saved : "";
  ::setenv("HAZE_SHADER_CACHE", cache.c_str(), 1);
  r = run(fmt::format("render {} --out {}", scene, (dir / "c").string()));
  if (saved)
    ::setenv("HAZE_SHADER_CACHE", saved_value.c_str(), 1);
  else
    ::unsetenv("HAZE_SHADER_CACHE");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(shaders(dir / "c")["compiled"].get<int>(), 0);
  // A folder that cannot be made (its parent is a file): one warning line, compiled in memory.
  const std::string file = write("not_a_folder", "x");
  r = run(fmt::format("render {} --out {} --shader-cache {}/cache", scene, (dir / "d").string(), file));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find(fmt::format("haze: warning: shader cache {}/cache: ", file)), std::string::npos)
      << r.out;
  EXPECT_EQ(r.out.find("warning", r.out.find("warning") + 1), std::string::npos) << "one warning: " << r.out;
  EXPECT_GE(shaders(dir / "d")["compiled"].get<int>(), 1);
}

// A full disk: every output fails loudly and the previous outputs stay as they were. The small filesystem is
// a tmpfs in a private user and mount namespace (unshare -r -m: no root needed), gone when the script ends.
TEST_F(Cli, FullDiskFailsLoudlyAndKeepsThePreviousOutputs) {
  const std::string scene = small_scene(), fs_dir = (dir / "small").string(),
                    saved = (dir / "saved").string();
  fs::create_directories(fs_dir);
  fs::create_directories(saved);
  for (const char* outputs : {"png", "exr", "stats"}) {
    const std::string file = std::string(outputs) == "png"   ? "frame_0000.png"
                             : std::string(outputs) == "exr" ? "frame_0000.exr"
                                                             : "stats.json";
    const std::string script = fmt::format(
        "set -e; mount -t tmpfs -o size=4m tmpfs {0}; "
        "{1} render {2} --out {0}/out --set render.outputs={3} > {4}/first.log 2>&1; "
        "cp {0}/out/{5} {4}/{5}; "
        "dd if=/dev/zero of={0}/fill bs=4096 > /dev/null 2>&1 || true; "
        "set +e; {1} render {2} --out {0}/out --set render.outputs={3} --set render.seed=7 > {4}/second.log "
        "2>&1; "
        "echo $? > {4}/rc; cmp -s {0}/out/{5} {4}/{5} && echo intact > {4}/intact; "
        "ls -a {0}/out > {4}/listing; true",
        fs_dir, HAZE_BIN, scene, outputs, saved, file);
    ASSERT_EQ(std::system(fmt::format("unshare -r -m sh -c '{}'", script).c_str()), 0) << outputs;
    auto read = [&](const char* name) {
      std::ifstream f(fs::path(saved) / name);
      std::stringstream ss;
      ss << f.rdbuf();
      return ss.str();
    };
    ASSERT_TRUE(fs::exists(fs::path(saved) / file))
        << outputs << ": the first run failed: " << read("first.log");
    EXPECT_NE(read("rc"), "0\n") << outputs << ": " << read("second.log");
    Result r{1, read("second.log")};
    expect_one_line_error(r, "No space left on device");
    EXPECT_EQ(read("intact"), "intact\n") << outputs << ": the previous " << file << " changed";
    EXPECT_EQ(read("listing").find(".tmp"), std::string::npos)
        << outputs << ": a temporary is left: " << read("listing");
  }
}

// A valid but absurd emitter (1e20 per channel, squares 1e40 beyond float): every layer stays finite, and
// stats.json counts the samples whose squares were clamped, every sample here since the plane fills the view.
TEST_F(Cli, BoundsThatMissTheMediumAreAnError) {
  const std::string scene = write("miss.json", R"({"camera": {"position": [0, 0, 5], "target": [0, 0, 0]},
    "media": [{"procedural": {"kind": "box", "size": 1}, "bounds_min": [3, 3, 3], "bounds_max": [4, 4, 4]}],
    "render": {"width": 8, "height": 8, "spp": 1}})");
  auto r = run(fmt::format("render {} --out {}", scene, (dir / "o").string()));
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(
      r.out.find("haze: error: " + scene + ": media[0].bounds_min/bounds_max: the box misses the medium"),
      std::string::npos)
      << r.out;
  const std::string error = r.out.substr(r.out.find("haze: error:"));
  EXPECT_EQ(std::count(error.begin(), error.end(), '\n'), 1) << r.out;  // one line
}

TEST_F(Cli, HugeEmitterStaysFiniteAndSaysSo) {
  const std::string scene = write("hot.json", R"({"camera": {"position": [0, 0, 1], "target": [0, 0, 0]},
    "surfaces": [{"mesh": {"kind": "plane", "size": [20, 20]}, "albedo": [0.7, 0.7, 0.7],
                  "emission": [1e20, 1e20, 1e20]}],
    "render": {"width": 16, "height": 12, "spp": 3}})");
  auto r = run(fmt::format("render {} --out {}", scene, (dir / "o").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto img = haze::render::read_exr((dir / "o/frame_0000.exr").string());
  for (size_t c = 0; c < img.channels.size(); ++c)
    for (float v : img.data[c]) ASSERT_TRUE(std::isfinite(v)) << img.channels[c];
  const auto st = nlohmann::json::parse(std::ifstream(dir / "o/stats.json"));
  EXPECT_EQ(st["frames"][0]["clamped_squares"], 16 * 12 * 3);
  EXPECT_EQ(st["frames"][0]["discarded"],
            nlohmann::json({{"non_finite", 0}, {"step_cap", 0}, {"majorant", 0}}));
  EXPECT_NE(st["notes"].dump().find("576 samples had a squared radiance above 2e+31"), std::string::npos)
      << st["notes"];
  EXPECT_NE(r.out.find("note: 576 samples had a squared radiance"), std::string::npos) << r.out;
}

TEST_F(Cli, HelpParamsNeedsNoScene) {
  auto r = run("render --help-params");
  ASSERT_EQ(r.code, 0) << r.out;
  for (const char* key : {"camera.fov_y", "render.spp", "media[].albedo", "denoise.surface.phi_luminance",
                          "guiding.probability", "lights.sun.irradiance"})
    EXPECT_NE(r.out.find(key), std::string::npos) << key;
  EXPECT_NE(r.out.find("default 45"), std::string::npos) << r.out.substr(0, 400);
  expect_one_line_error(run("render"), "needs a scene file and --out DIR");
}

TEST_F(Cli, RenderWritesLayersPreviewAndStats) {
  auto r = run(fmt::format("render {} --out {}", small_scene(), (dir / "out").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  auto img = haze::render::read_exr((dir / "out/frame_0000.exr").string());
  EXPECT_EQ(img.width, 24);
  EXPECT_EQ(img.height, 16);
  for (const char* c : {"R", "G", "B", "volume.R", "surface.R", "transmittance.Y", "depth.Z", "variance.R"})
    EXPECT_NO_THROW(img.channel(c)) << c;
  double sum = 0;
  for (float v : img.channel("volume.R")) {
    ASSERT_TRUE(std::isfinite(v));
    sum += v;
  }
  EXPECT_GT(sum, 0.0);  // the sunlit haze scatters
  EXPECT_TRUE(fs::exists(dir / "out/frame_0000.png"));
  auto st = nlohmann::json::parse(std::ifstream(dir / "out/stats.json"));
  EXPECT_TRUE(st["passes"].contains("trace"));
  EXPECT_GT(st["memory"]["total"].get<uint64_t>(), 0u);
  EXPECT_EQ(st["features"], "haze+sun");
  EXPECT_FALSE(st["device"]["name"].get<std::string>().empty());
  // No buffer for features the scene does not use.
  for (const auto& e : st["memory"]["entries"]) {
    EXPECT_NE(e["name"], "nanovdb grids");
    EXPECT_NE(e["name"], "majorant grid");
    EXPECT_NE(e["name"], "minorant grid");
  }
}

TEST_F(Cli, SameSeedSameImageOtherSeedOtherImage) {
  std::string scene = small_scene();
  auto a = run(fmt::format("render {} --out {}", scene, (dir / "a").string()));
  auto b = run(fmt::format("render {} --out {}", scene, (dir / "b").string()));
  auto c = run(fmt::format("render {} --out {} --set render.seed=2", scene, (dir / "c").string()));
  ASSERT_EQ(a.code, 0) << a.out;
  ASSERT_EQ(b.code, 0) << b.out;
  ASSERT_EQ(c.code, 0) << c.out;
  auto ia = haze::render::read_exr((dir / "a/frame_0000.exr").string());
  auto ib = haze::render::read_exr((dir / "b/frame_0000.exr").string());
  auto ic = haze::render::read_exr((dir / "c/frame_0000.exr").string());
  EXPECT_EQ(ia.channel("R"), ib.channel("R"));
  EXPECT_NE(ia.channel("R"), ic.channel("R"));
}

TEST_F(Cli, MissingSceneFile) {
  expect_one_line_error(run(fmt::format("render {}/nope.json --out {}", dir.string(), dir.string())),
                        "nope.json");
}

// Devices and pipes are refused by type before anything reads them (/dev/zero never ends).
TEST_F(Cli, DeviceFilesAreRefusedByType) {
  expect_one_line_error(run(fmt::format("render /dev/zero --out {}", (dir / "a").string())),
                        "cannot open scene file /dev/zero: not a regular file");
  for (const char* key : {"surfaces[0].file", "surfaces[0].albedo_texture", "media[0].file"}) {
    const std::string k = key;
    const std::string body =
        k == "media[0].file" ? R"({"media": [{"file": "/dev/zero"}]})"
        : k == "surfaces[0].file"
            ? R"({"surfaces": [{"file": "/dev/zero"}]})"
            : R"({"surfaces": [{"mesh": {"kind": "plane"}, "albedo_texture": "/dev/zero"}]})";
    expect_one_line_error(
        run(fmt::format("render {} --out {}", write("dev.json", body), (dir / "b").string())),
        k + ": /dev/zero is a device, pipe or socket, not a regular file");
  }
  expect_one_line_error(run("vdb info /dev/zero"), "/dev/zero: not a regular file");
}

// A procedural medium beyond OpenVDB's 32-bit index range: one line naming the scene file and the key
// (OpenVDB's own "can't construct a dense grid with an empty bounding box" named neither).
// `haze render` ends with its figures (samples, time, the three most expensive passes, memory per category),
// `haze stats` prints the same for the folder, previews are RGB, and `haze tonemap` writes any layer as one.
TEST_F(Cli, RenderSummaryStatsAndTonemap) {
  const std::string out = (dir / "out").string();
  auto r = run(fmt::format("render {} --out {}", small_scene(", \"exposure\": 1.5"), out));
  ASSERT_EQ(r.code, 0) << r.out;
  const size_t at = r.out.find("4 spp, 1 frame, ");
  ASSERT_NE(at, std::string::npos) << r.out;
  const std::string summary = r.out.substr(at);
  const std::string passes = summary.substr(summary.find("most expensive passes (GPU ms per frame): "));
  // The first pass named is stats.json's most expensive one (which pass that is depends on the scene).
  const auto st_json = nlohmann::json::parse(std::ifstream(dir / "out/stats.json"));
  ASSERT_TRUE(st_json["passes"].contains("trace")) << st_json["passes"].dump();
  std::string top_pass;
  double top_ms = -1;
  for (const auto& [k, x] : st_json["passes"].items())
    if (x.value("total_ms", 0.0) > top_ms) top_ms = x.value("total_ms", 0.0), top_pass = k;
  EXPECT_EQ(passes.find("most expensive passes (GPU ms per frame): " + top_pass + " "), 0u) << summary;
  EXPECT_NE(summary.find("per category in MB: "), std::string::npos) << summary;
  EXPECT_NE(summary.find("per-frame temporaries"), std::string::npos) << summary;
  auto st = run("stats " + out);
  ASSERT_EQ(st.code, 0) << st.out;
  EXPECT_EQ(st.out, summary);
  expect_one_line_error(run("stats " + dir.string()), "no stats.json or results.jsonl");
  // A `haze denoise` folder: its passes and memory, and no sample count or render time it does not have.
  ASSERT_EQ(run(fmt::format("denoise {} --out {}/dn", out, dir.string())).code, 0);
  st = run(fmt::format("stats {}/dn", dir.string()));
  ASSERT_EQ(st.code, 0) << st.out;
  EXPECT_EQ(st.out.rfind("1 frame, GPU ", 0), 0u) << st.out;
  EXPECT_NE(st.out.find("svgf.surface."), std::string::npos) << st.out;

  auto png_info = [](const std::string& path) {
    int w = 0, h = 0, n = 0;
    EXPECT_TRUE(stbi_info(path.c_str(), &w, &h, &n)) << path;
    return std::array<int, 3>{w, h, n};
  };
  EXPECT_EQ(png_info(out + "/frame_0000.png"), (std::array<int, 3>{24, 16, 3}));
  // The denoised layer at the scene's exposure (from stats.json) is the preview the renderer wrote.
  const std::string base = (dir / "base.png").string();
  r = run(fmt::format("tonemap {}/frame_0000.exr --layer denoised --out {}", out, base));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("+1.5 EV, aces, the scene's from"), std::string::npos) << r.out;
  int w = 0, h = 0, n = 0;
  unsigned char* a = stbi_load(base.c_str(), &w, &h, &n, 3);
  unsigned char* b = stbi_load((out + "/frame_0000.png").c_str(), &w, &h, &n, 3);
  ASSERT_TRUE(a && b);
  int worst = 0;
  for (int i = 0; i < w * h * 3; ++i) worst = std::max(worst, std::abs(int(a[i]) - int(b[i])));
  stbi_image_free(a);
  stbi_image_free(b);
  EXPECT_LE(worst, 1);  // CPU and GPU round alike but for the last bit
  for (const char* layer : {"volume", "depth", "motion", "transmittance"}) {
    const std::string p = (dir / fmt::format("{}.png", layer)).string();
    r = run(fmt::format("tonemap {}/frame_0000.exr --layer {} --exposure -2 --out {}", out, layer, p));
    ASSERT_EQ(r.code, 0) << r.out;
    EXPECT_EQ(png_info(p), (std::array<int, 3>{24, 16, 3})) << layer;
  }
  expect_one_line_error(run(fmt::format("tonemap {}/frame_0000.exr --layer nope --out {}/x.png", out, out)),
                        "pass --layer with one of: ");
  expect_one_line_error(
      run(fmt::format("tonemap {}/frame_0000.exr --tonemap filmic --out {}/x.png", out, out)),
      "not one of aces, reinhard, clamp");
}

// render.time_budget_s: samples until the budget is spent, counted in stats.json and the summary.
TEST_F(Cli, TimeBudgetSamplesUntilSpent) {
  const std::string scene = small_scene();
  auto samples_with = [&](double budget) {
    const std::string out = (dir / fmt::format("b{}", budget)).string();
    auto r = run(fmt::format("render {} --out {} --set render.time_budget_s={}", scene, out, budget));
    EXPECT_EQ(r.code, 0) << r.out;
    const auto st = nlohmann::json::parse(std::ifstream(out + "/stats.json"));
    const int n = st["frames"][0]["samples"].get<int>();
    EXPECT_NE(r.out.find(fmt::format("{} spp, 1 frame, ", n)), std::string::npos) << r.out;
    EXPECT_GE(st["frames"][0]["render_s"].get<double>(), budget);
    return n;
  };
  const int small = samples_with(0.05), large = samples_with(0.5);
  EXPECT_GE(small, 1);
  EXPECT_GT(large, 2 * small);  // 10x the budget: samples cost about the same each
}

// Mesh, procedural and grid errors name the scene file and the key, list what is valid, and come before the
// device starts; the hint about relative paths is given for relative paths only.
TEST_F(Cli, PartSpecErrorsNameFileAndKeyBeforeTheDevice) {
  auto scene = [&](const std::string& body) { return write("p.json", body); };
  auto render = [&](const std::string& s) {
    return run(fmt::format("render {} --out {}/o", s, dir.string()));
  };
  std::string s = scene(R"({"surfaces": [{"mesh": {"kind": "plane", "sise": [2, 2]}}]})");
  auto r = render(s);
  expect_one_line_error(r,
                        s + ": surfaces[0].mesh.sise: unknown key for a plane mesh; its keys are kind, size");
  EXPECT_EQ(r.out.find("device:"), std::string::npos) << r.out;
  s = scene(R"({"media": [{"procedural": {"kind": "box", "densty": 2}}]})");
  r = render(s);
  expect_one_line_error(r, s + ": media[0].procedural: unknown key 'densty' (known: kind,");
  EXPECT_EQ(r.out.find("device:"), std::string::npos) << r.out;
  ASSERT_EQ(run(fmt::format("vdb make box --out {}/box.vdb", dir.string())).code, 0);
  s = scene(R"({"media": [{"file": "box.vdb", "grid": "dens"}]})");
  r = render(s);
  expect_one_line_error(r, s + ": media[0].grid:");
  EXPECT_NE(r.out.find("set media[0].grid to one of these"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("device:"), std::string::npos) << r.out;
  s = scene(R"({"media": [{"file": "nothere.vdb"}]})");
  expect_one_line_error(render(s), "relative paths start at the scene file's folder");
  s = scene(R"({"media": [{"file": "/nonexistent/nothere.vdb"}]})");
  r = render(s);
  expect_one_line_error(r, "no such file: /nonexistent/nothere.vdb; check the path");
  EXPECT_EQ(r.out.find("relative paths"), std::string::npos) << r.out;
}

TEST_F(Cli, ProceduralMediumOutOfIndexRange) {
  const std::string scene =
      write("far.json", R"({"media": [{"procedural": {"kind": "cloud", "voxel_size": 0.1,
      "center": [1.8e19, 0, 0], "size": [2, 2, 2]}}]})");
  expect_one_line_error(
      run(fmt::format("render {} --out {}", scene, (dir / "a").string())),
      scene + ": media[0].procedural: key 'center' puts the grid 1.8e+20 voxels from the origin");
}

TEST_F(Cli, MalformedJson) {
  expect_one_line_error(
      run(fmt::format("render {} --out {}", write("bad.json", "{ \"camera\": "), dir.string())), "bad.json");
}

TEST_F(Cli, UnknownKeyIsNamed) {
  std::string s = write("s.json", R"({"render": {"sppp": 4}})");
  expect_one_line_error(run(fmt::format("render {} --out {}", s, dir.string())), "render.sppp");
}

TEST_F(Cli, NegativeDensityScale) {
  std::string s = write("s.json", R"({"media": [{"procedural": {"kind": "box"}, "density_scale": -1}]})");
  expect_one_line_error(run(fmt::format("render {} --out {}", s, dir.string())), "density_scale");
}

TEST_F(Cli, ZeroSizeImage) {
  expect_one_line_error(run(fmt::format("render {} --out {} --size 0x16", small_scene(), dir.string())),
                        "render.width");
}

// --spp is read as the scene file reads render.spp: 1e3 is a number, 0 is out of range (one line, no
// 309-digit range), a word is no number.
TEST_F(Cli, SppReadsLikeTheSceneFile) {
  const std::string scene = small_scene();
  auto r = run(fmt::format("render {} --out {} --spp 2e0", scene, (dir / "a").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(nlohmann::json::parse(std::ifstream(dir / "a/stats.json"))["samples"], 2);
  r = run(fmt::format("render {} --out {} --spp 0", scene, (dir / "b").string()));
  expect_one_line_error(r, "render.spp: must be in [1, 1048576], got 0");
  EXPECT_LT(r.out.size(), 300u) << r.out;
  expect_one_line_error(run(fmt::format("render {} --out {} --spp lots", scene, (dir / "c").string())),
                        "render.spp: expected a number");
}

TEST_F(Cli, UnknownSetPath) {
  expect_one_line_error(
      run(fmt::format("render {} --out {} --set render.nope=1", small_scene(), dir.string())), "render.nope");
}

TEST_F(Cli, MissingAndInvalidVdbFiles) {
  std::string s = write("s.json", R"({"media": [{"file": "missing.vdb"}]})");
  expect_one_line_error(run(fmt::format("render {} --out {}", s, (dir / "o").string())), "missing.vdb");
  write("garbage.vdb", "this is not a vdb file");
  std::string g = write("g.json", R"({"media": [{"file": "garbage.vdb"}]})");
  expect_one_line_error(run(fmt::format("render {} --out {}", g, (dir / "o").string())), "garbage.vdb");
  expect_one_line_error(run(fmt::format("vdb info {}", (dir / "garbage.vdb").string())), "garbage.vdb");
}

TEST_F(Cli, UnwritableOutputDirectory) {
  expect_one_line_error(run(fmt::format("render {} --out /proc/haze-out", small_scene())), "/proc/haze-out");
}

TEST_F(Cli, FailedRunLeavesExistingOutputsIntact) {
  fs::create_directories(dir / "out");
  write("out/frame_0000.exr", "precious");
  std::string s = write("s.json", R"({"render": {"spp": -3}})");
  auto r = run(fmt::format("render {} --out {}", s, (dir / "out").string()));
  EXPECT_NE(r.code, 0);
  std::stringstream ss;
  ss << std::ifstream(dir / "out/frame_0000.exr").rdbuf();
  EXPECT_EQ(ss.str(), "precious");
  // And nothing temporary is left behind.
  for (const auto& e : fs::directory_iterator(dir / "out")) EXPECT_EQ(e.path().filename(), "frame_0000.exr");
}

// A run that fails part-way (a VDB sequence whose second file is truncated) replaces none of the folder's
// outputs: frames are staged and renamed only when every frame rendered.
TEST_F(Cli, FailingSequenceReplacesNoOutput) {
  for (int f = 0; f < 2; ++f)
    ASSERT_EQ(run(fmt::format("vdb make box --out {} --voxel-size 0.1 --size 1 1 1",
                              (dir / fmt::format("seq_{:04d}.vdb", f)).string()))
                  .code,
              0);
  const std::string scene = write("seq.json", R"({
    "camera": {"position": [0, 0, 3], "target": [0, 0, 0]},
    "media": [{"file": "seq_####.vdb"}], "lights": {"sun": {"direction": [0, 1, 0]}},
    "render": {"width": 16, "height": 12, "spp": 1, "frames": "0:1"}})");
  const fs::path out = dir / "out";
  auto r = run(fmt::format("render {} --out {}", scene, out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const std::string exr = file_bytes(out / "frame_0000.exr"), stats = file_bytes(out / "stats.json");
  // A killed run's temporary (a process id that no longer exists) is cleaned up by the next run.
  write("out/.frame_0000.exr.tmp999999999", "left by a killed run");
  fs::resize_file(dir / "seq_0001.vdb", 100);
  r = run(fmt::format("render {} --out {} --set render.seed=9", scene, out.string()));
  expect_one_line_error(r, "seq_0001.vdb");
  EXPECT_EQ(file_bytes(out / "frame_0000.exr"), exr) << "frame 0 was replaced by a failing run";
  EXPECT_EQ(file_bytes(out / "stats.json"), stats);
  expect_no_temporaries(out);
}

// A stats.json that is a directory is refused before anything renders or is replaced.
TEST_F(Cli, OutputThatIsADirectoryIsRefusedUpFront) {
  fs::create_directories(dir / "out/stats.json");
  write("out/frame_0000.exr", "precious");
  auto r = run(fmt::format("render {} --out {}", small_scene(), (dir / "out").string()));
  expect_one_line_error(r, "stats.json: it is a directory");
  EXPECT_EQ(r.out.find("device:"), std::string::npos) << "checked before the device starts: " << r.out;
  EXPECT_EQ(file_bytes(dir / "out/frame_0000.exr"), "precious");
  expect_no_temporaries(dir / "out");
}

// A corrupt count or length in a .vdb (the grid's metadata count at 0x80, the first name's length at 0x84)
// gives a one-line error in bounded memory and time; before, OpenVDB allocated until the machine ran out.
TEST_F(Cli, CorruptVdbHeaderIsBoundedAndNamed) {
  const fs::path good = dir / "box.vdb";
  ASSERT_EQ(run(fmt::format("vdb make box --out {} --voxel-size 0.1 --size 1 1 1", good.string())).code, 0);
  for (int offset : {0x80, 0x84}) {
    const fs::path bad = dir / fmt::format("bad_{:x}.vdb", offset);
    std::string bytes = file_bytes(good);
    ASSERT_GT(bytes.size(), size_t(offset + 4));
    bytes.replace(size_t(offset), 4, "\xff\xff\xff\xff");
    std::ofstream(bad, std::ios::binary) << bytes;
    // 1 GB of address space and 60 s: far more than a 76 kB file needs, far less than the corrupt length.
    const int rc =
        std::system(fmt::format("bash -c 'ulimit -v 1000000; timeout 60 {} vdb info {} > {}/info.log 2>&1'",
                                HAZE_BIN, bad.string(), dir.string())
                        .c_str());
    const Result r{WEXITSTATUS(rc), file_bytes(dir / "info.log")};
    expect_one_line_error(r, bad.string() + ": corrupt .vdb: reading it asked for");
    EXPECT_NE(WEXITSTATUS(rc), 124) << "timed out";
    const std::string scene = write("corrupt.json", fmt::format(R"({{"media": [{{"file": "{}"}}],
        "lights": {{"sun": {{}}}}, "render": {{"width": 8, "height": 8, "spp": 1}}}})",
                                                                bad.string()));
    expect_one_line_error(run(fmt::format("render {} --out {}", scene, (dir / "out").string())),
                          bad.string() + ": corrupt .vdb");
  }
}

TEST_F(Cli, VdbMakeAndInfo) {
  std::string f = (dir / "cloud.vdb").string();
  auto m = run(fmt::format("vdb make cloud --out {} --voxel-size 0.1 --size 2 2 2 --seed 4", f));
  ASSERT_EQ(m.code, 0) << m.out;
  auto i = run(fmt::format("vdb info {} --json", f));
  ASSERT_EQ(i.code, 0) << i.out;
  auto j = nlohmann::json::parse(i.out);
  ASSERT_FALSE(j.empty());
  std::string dump = j.dump();
  EXPECT_NE(dump.find("density"), std::string::npos);
  expect_one_line_error(run(fmt::format("vdb make blob --out {}", f)), "blob");
}

// A sequence with a velocity: one file per frame, the cloud moved by f * --move through its transform, and
// vel.x/y/z = --move * --fps over it; a scene renders it with its velocity; the errors are one line.
TEST_F(Cli, VdbMakeWritesAMovingSequenceWithVelocity) {
  const std::string pattern = (dir / "smoke_##.vdb").string();
  auto m =
      run(fmt::format("vdb make cloud --out {} --voxel-size 0.1 --size 1 1 1 --frames 0:2 --move 0.2 0 -0.1 "
                      "--velocity --fps 10",
                      pattern));
  ASSERT_EQ(m.code, 0) << m.out;
  double x0 = 0;
  for (int f = 0; f <= 2; ++f) {
    auto i = run(fmt::format("vdb info {} --json", (dir / fmt::format("smoke_{:02d}.vdb", f)).string()));
    ASSERT_EQ(i.code, 0) << i.out;
    auto j = nlohmann::json::parse(i.out);
    ASSERT_EQ(j.size(), 4u);
    EXPECT_EQ(j[0]["name"], "density");
    const double x = j[0]["world_min"][0].get<double>();
    if (f == 0) x0 = x;
    EXPECT_NEAR(x - x0, 0.2 * f, 1e-9);
    const double want[3] = {2, 0, -1};
    for (int c = 0; c < 3; ++c) {
      EXPECT_EQ(j[c + 1]["name"], std::string("vel.") + "xyz"[c]);
      EXPECT_NEAR(j[c + 1]["value_min"].get<double>(), want[c], 1e-6);
      EXPECT_NEAR(j[c + 1]["value_max"].get<double>(), want[c], 1e-6);
    }
  }
  std::string s = write("moving.json", R"({"media": [{"file": "smoke_##.vdb", "velocity": {"grid": "vel"}}],
    "lights": {"sun": {}}, "render": {"width": 16, "height": 12, "spp": 2, "fps": 10, "frames": "0:2"}})");
  auto r = run(fmt::format("render {} --out {}", s, (dir / "o").string()));
  EXPECT_EQ(r.code, 0) << r.out;
  std::string bad = write("bad.json", R"({"media": [{"file": "smoke_##.vdb", "velocity": {"grid": "v"}}],
    "render": {"frames": "0:1"}})");
  expect_one_line_error(run(fmt::format("render {} --out {}", bad, (dir / "o2").string())),
                        "media[0].velocity.grid");
  expect_one_line_error(run(fmt::format("vdb make cloud --out {} --frames 0:2", (dir / "x.vdb").string())),
                        "run of #");
  expect_one_line_error(run(fmt::format("vdb make cloud --out {}", (dir / "x_#.vdb").string())), "--frames");
}

TEST_F(Cli, PipelineCacheFileIsWritten) {
  std::string cache = (dir / "pipelines.bin").string();
  auto r =
      run(fmt::format("--pipeline-cache {} render {} --out {}", cache, small_scene(), (dir / "o").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_TRUE(fs::exists(cache));
  auto again =
      run(fmt::format("--pipeline-cache {} render {} --out {}", cache, small_scene(), (dir / "o").string()));
  EXPECT_EQ(again.code, 0) << again.out;
}

TEST_F(Cli, WrongGridTypeIsNamed) {
  // A scene that asks for a grid the file does not have: the error lists what is there.
  std::string f = (dir / "cloud.vdb").string();
  ASSERT_EQ(run(fmt::format("vdb make cloud --out {} --voxel-size 0.2 --size 2 2 2", f)).code, 0);
  std::string s = write("s.json", R"({"media": [{"file": "cloud.vdb", "grid": "smoke"}]})");
  expect_one_line_error(run(fmt::format("render {} --out {}", s, (dir / "o").string())), "smoke");
}

TEST_F(Cli, AnimatedFramesAreWrittenAndDeterministicPerFrame) {
  std::string s = write("anim.json", R"({
    "camera": {"position": [0, 1, 5], "target": [0, 1, 0]},
    "media": [{"procedural": {"kind": "cloud", "voxel_size": 0.1, "size": [2, 2, 2]}}],
    "lights": {"sun": {"direction": [0.3, 1, 0.2]}},
    "render": {"width": 16, "height": 12, "spp": 2},
    "animation": {"tracks": [
      {"path": "camera.position", "keys": [{"frame": 0, "value": [0, 1, 5]}, {"frame": 2, "value": [2, 1, 4]}]},
      {"path": "media[0].transform.translate", "keys": [{"frame": 0, "value": [0, 0, 0]}, {"frame": 2, "value": [0.5, 0, 0]}]}]}
  })");
  auto all = run(fmt::format("render {} --out {} --frames 0:2", s, (dir / "all").string()));
  ASSERT_EQ(all.code, 0) << all.out;
  for (int f = 0; f <= 2; ++f) EXPECT_TRUE(fs::exists(dir / fmt::format("all/frame_{:04d}.exr", f)));
  auto st = nlohmann::json::parse(std::ifstream(dir / "all/stats.json"));
  ASSERT_EQ(st["frames"].size(), 3u);
  // Frame 1 alone equals frame 1 of the sequence: frames depend on the seed and their number only.
  auto one = run(fmt::format("render {} --out {} --frames 1:1", s, (dir / "one").string()));
  ASSERT_EQ(one.code, 0) << one.out;
  auto a = haze::render::read_exr((dir / "all/frame_0001.exr").string());
  auto b = haze::render::read_exr((dir / "one/frame_0001.exr").string());
  EXPECT_EQ(a.channel("R"), b.channel("R"));
  auto c = haze::render::read_exr((dir / "all/frame_0002.exr").string());
  EXPECT_NE(a.channel("R"), c.channel("R"));
  expect_one_line_error(run(fmt::format("render {} --out {} --frames 3:1", s, (dir / "bad").string())),
                        "--frames");
}

// OBJ meshes and albedo textures: each bad file gets a one-line error naming it, and outputs already
// written stay as they were. NaN/Inf vertices and zero-area triangles are dropped with a note instead.
TEST_F(Cli, BadMeshesAndTexturesAreNamed) {
  fs::create_directories(dir / "out");
  write("out/frame_0000.exr", "precious");
  auto scene_with = [&](const std::string& surface) {
    return write("s.json", fmt::format(R"({{
      "camera": {{"position": [0, 0, 3], "target": [0, 0, 0]}},
      "lights": {{"sun": {{"direction": [0.3, 1, 0.2]}}}},
      "surfaces": [{}],
      "render": {{"width": 16, "height": 12, "spp": 2}}
    }})",
                                       surface));
  };
  auto render_into_out = [&](const std::string& scene) {
    return run(fmt::format("render {} --out {}", scene, (dir / "out").string()));
  };
  expect_one_line_error(render_into_out(scene_with(R"({"file": "missing.obj"})")), "missing.obj");
  write("bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  expect_one_line_error(render_into_out(scene_with(R"({"file": "bad.obj"})")), "bad.obj");
  write("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
  expect_one_line_error(render_into_out(scene_with(R"({"file": "flat.obj"})")), "flat.obj");
  write("quad.obj", "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3 4\n");
  expect_one_line_error(
      render_into_out(scene_with(R"({"file": "quad.obj", "albedo_texture": "missing.png"})")), "missing.png");
  write("garbage.png", "not an image at all");
  expect_one_line_error(
      render_into_out(scene_with(R"({"mesh": {"kind": "plane"}, "albedo_texture": "garbage.png"})")),
      "garbage.png");
  // A texture needs texture coordinates; quad.obj has none (the error names the surface and the file).
  write("one.ppm", std::string("P6 1 1 255\n") + char(200) + char(100) + char(50));
  auto no_uvs = render_into_out(scene_with(R"({"file": "quad.obj", "albedo_texture": "one.ppm"})"));
  expect_one_line_error(no_uvs, "surfaces[0].albedo_texture");
  EXPECT_NE(no_uvs.out.find("quad.obj"), std::string::npos) << no_uvs.out;
  std::stringstream ss;
  ss << std::ifstream(dir / "out/frame_0000.exr").rdbuf();
  EXPECT_EQ(ss.str(), "precious");

  // Bad triangles are dropped, counted on the console and in stats.json; the render goes on.
  write("some_bad.obj", "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv 1e39 0 0\nf 1 2 3\nf 1 2 4\nf 1 1 2\n");
  auto ok = run(
      fmt::format("render {} --out {}", scene_with(R"({"file": "some_bad.obj"})"), (dir / "ok").string()));
  ASSERT_EQ(ok.code, 0) << ok.out;
  EXPECT_NE(ok.out.find("dropped 2 triangles"), std::string::npos) << ok.out;
  auto st = nlohmann::json::parse(std::ifstream(dir / "ok/stats.json"));
  EXPECT_NE(st["notes"].dump().find("1 with NaN/Inf vertices, 1 degenerate"), std::string::npos)
      << st["notes"];
  // A textured primitive renders, with the texture variant and its buffers.
  auto tex = run(fmt::format("render {} --out {}",
                             scene_with(R"({"mesh": {"kind": "plane"}, "albedo_texture": "one.ppm"})"),
                             (dir / "tex").string()));
  ASSERT_EQ(tex.code, 0) << tex.out;
  auto ts = nlohmann::json::parse(std::ifstream(dir / "tex/stats.json"));
  EXPECT_EQ(ts["features"], "sun+surfaces+texture");
  EXPECT_NE(ts["memory"].dump().find("albedo textures"), std::string::npos);
}

// The largest difference in a channel of two frames, over the larger of 1e-3 and the first frame's peak.
double relative_difference(const haze::render::ExrImage& a, const haze::render::ExrImage& b, const char* c) {
  const auto &u = a.channel(c), &v = b.channel(c);
  double worst = 0, scale = 1e-3;
  for (size_t i = 0; i < u.size(); ++i) {
    worst = std::max(worst, double(std::abs(u[i] - v[i])));
    scale = std::max(scale, double(std::abs(u[i])));
  }
  return worst / scale;
}

// Renders `scene` into dir/r, then haze denoise over dir/r into dir/d.
void render_and_denoise(const std::string& scene, const fs::path& dir) {
  auto r = run(fmt::format("render {} --out {}", scene, (dir / "r").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  auto d = run(fmt::format("denoise {} --out {}", (dir / "r").string(), (dir / "d").string()));
  ASSERT_EQ(d.code, 0) << d.out;
}

// haze denoise on haze's own EXR sequence reproduces the renderer's denoised layers (same inputs, same
// instance), and bad sequences are named.
TEST_F(Cli, DenoiseAnExrSequence) {
  std::string s = write("anim.json", R"({
    "camera": {"position": [0, 1, 4], "target": [0, 0.5, 0]},
    "surfaces": [{"mesh": {"kind": "box", "size": [3, 0.2, 3]}, "albedo": [0.7, 0.6, 0.5]},
                 {"mesh": {"kind": "sphere", "radius": 0.5}, "transform": {"translate": [0, 0.6, 0]}}],
    "lights": {"sun": {"direction": [0.3, 1, 0.2]}, "environment": {"color": [0.3, 0.4, 0.6]}},
    "render": {"width": 40, "height": 24, "spp": 2, "max_depth": 2},
    "animation": {"tracks": [{"path": "camera.position",
                              "keys": [{"frame": 0, "value": [0, 1, 4]}, {"frame": 2, "value": [0.4, 1, 3.8]}]}]}
  })");
  ASSERT_NO_FATAL_FAILURE(render_and_denoise(s, dir));
  for (int f = 0; f <= 2; ++f) {
    auto a = haze::render::read_exr((dir / fmt::format("r/frame_{:04d}.exr", f)).string());
    auto b = haze::render::read_exr((dir / fmt::format("d/frame_{:04d}.exr", f)).string());
    EXPECT_TRUE(fs::exists(dir / fmt::format("d/frame_{:04d}.png", f)));
    for (const char* c :
         {"denoised.R", "surface_denoised.G", "surface_history.Y", "surface_denoised_variance.Y"}) {
      EXPECT_LE(relative_difference(a, b, c), 1e-3) << "frame " << f << " " << c;
    }
  }
  auto st = nlohmann::json::parse(std::ifstream(dir / "d/stats.json"));
  EXPECT_EQ(st["frames"].size(), 3u);
  EXPECT_TRUE(st["passes"].contains("svgf.surface.accumulate"));
  // Classic mode through --set.
  auto c = run(fmt::format("denoise {} --out {} --set denoise.surface.mode=classic", (dir / "r").string(),
                           (dir / "c").string()));
  ASSERT_EQ(c.code, 0) << c.out;
  EXPECT_FALSE(nlohmann::json::parse(std::ifstream(dir / "c/stats.json"))["passes"].contains(
      "svgf.surface.percentiles"));

  expect_one_line_error(
      run(fmt::format("denoise {} --out {}", (dir / "none").string(), (dir / "o").string())), "none");
  // A corrupt second frame: the earlier outputs in --out stay as they were, no temporary is left.
  const std::string d0 = file_bytes(dir / "d/frame_0000.exr"), p0 = file_bytes(dir / "d/frame_0000.png");
  fs::resize_file(dir / "r/frame_0001.exr", 200);
  expect_one_line_error(run(fmt::format("denoise {} --out {}", (dir / "r").string(), (dir / "d").string())),
                        "frame_0001.exr");
  EXPECT_EQ(file_bytes(dir / "d/frame_0000.exr"), d0);
  EXPECT_EQ(file_bytes(dir / "d/frame_0000.png"), p0);
  expect_no_temporaries(dir / "d");
  fs::create_directories(dir / "empty");
  expect_one_line_error(
      run(fmt::format("denoise {} --out {}", (dir / "empty").string(), (dir / "o").string())),
      "no .exr files");
  // A frame without motion vectors: the file and the layer are named.
  fs::create_directories(dir / "nomotion");
  std::vector<float> plane(4, 1.f);
  haze::render::write_exr_channels((dir / "nomotion/f.exr").string(), 2, 2,
                                   {{"R", &plane}, {"G", &plane}, {"B", &plane}, {"depth.Z", &plane}});
  auto e = run(fmt::format("denoise {} --out {}", (dir / "nomotion").string(), (dir / "o").string()));
  expect_one_line_error(e, "f.exr");
  EXPECT_NE(e.out.find("no channel"), std::string::npos) << e.out;
  expect_one_line_error(run(fmt::format("denoise {} --out {} --set denoise.surface.phi_luminance=-1",
                                        (dir / "r").string(), (dir / "o").string())),
                        "denoise.surface.phi_luminance");
}

// haze denoise runs the volume instance too where the sequence has a volume signal: on haze's own frames of
// a hazy scene it reproduces the renderer's volume layers (virtual-point motion) and the composite.
TEST_F(Cli, DenoiseAnExrSequenceWithAVolume) {
  std::string s = write("haze.json", R"({
    "camera": {"position": [0, 1, 4], "target": [0, 0.5, 0]},
    "surfaces": [{"mesh": {"kind": "box", "size": [3, 0.2, 3]}, "albedo": [0.7, 0.6, 0.5]}],
    "haze": {"sigma_t": 0.3, "albedo": [0.9, 0.9, 0.9], "bounded": true,
             "bounds_min": [-1.5, 0.1, -1.5], "bounds_max": [1.5, 1.5, 1.5]},
    "lights": {"sun": {"direction": [0.3, 1, 0.2]}},
    "render": {"width": 32, "height": 24, "spp": 2, "max_depth": 2},
    "animation": {"tracks": [{"path": "camera.position",
                              "keys": [{"frame": 0, "value": [0, 1, 4]}, {"frame": 2, "value": [0.4, 1, 3.8]}]}]}
  })");
  ASSERT_NO_FATAL_FAILURE(render_and_denoise(s, dir));
  for (int f = 0; f <= 2; ++f) {
    auto a = haze::render::read_exr((dir / fmt::format("r/frame_{:04d}.exr", f)).string());
    auto b = haze::render::read_exr((dir / fmt::format("d/frame_{:04d}.exr", f)).string());
    for (const char* c : {"denoised.R", "surface_denoised.G", "volume_denoised.R", "volume_denoised.B",
                          "volume_history.Y", "volume_denoised_variance.Y"}) {
      EXPECT_LE(relative_difference(a, b, c), 1e-3) << "frame " << f << " " << c;
    }
  }
  auto st = nlohmann::json::parse(std::ifstream(dir / "d/stats.json"));
  EXPECT_TRUE(st["passes"].contains("svgf.volume.accumulate"));
  EXPECT_EQ(st["volume_denoise"]["motion"], "virtual_points");
  // The scene's one sun: each frame's EXR header carries its image (haze.epipole), which the volume
  // instance's epipolar term reads, as the renderer's did (the layers above agree).
  EXPECT_TRUE(st["volume_denoise"]["epipolar_term"].get<bool>());
  EXPECT_TRUE(nlohmann::json::parse(std::ifstream(dir / "r/stats.json"))["volume_denoise"]["epipolar_term"]);
  EXPECT_TRUE(haze::render::read_exr((dir / "r/frame_0001.exr").string()).epipole.has_value());
  // Frames without it (written by another tool): the term is off, and a note says so.
  fs::create_directories(dir / "plain");
  for (int f = 0; f <= 2; ++f) {
    auto a = haze::render::read_exr((dir / fmt::format("r/frame_{:04d}.exr", f)).string());
    std::vector<std::pair<std::string, const std::vector<float>*>> all;
    for (size_t c = 0; c < a.channels.size(); ++c) all.push_back({a.channels[c], &a.data[c]});
    haze::render::write_exr_channels((dir / fmt::format("plain/frame_{:04d}.exr", f)).string(), a.width,
                                     a.height, all);
  }
  auto plain = run(fmt::format("denoise {} --out {}", (dir / "plain").string(), (dir / "dp").string()));
  ASSERT_EQ(plain.code, 0) << plain.out;
  EXPECT_NE(plain.out.find("note:"), std::string::npos) << plain.out;
  EXPECT_NE(plain.out.find("haze.epipole"), std::string::npos) << plain.out;
  auto sp = nlohmann::json::parse(std::ifstream(dir / "dp/stats.json"));
  EXPECT_FALSE(sp["volume_denoise"]["epipolar_term"].get<bool>());
  EXPECT_EQ(sp["notes"].size(), 1u);
  // A header attribute that is not finite: the file is named.
  {
    auto a = haze::render::read_exr((dir / "r/frame_0000.exr").string());
    std::vector<std::pair<std::string, const std::vector<float>*>> all;
    for (size_t c = 0; c < a.channels.size(); ++c) all.push_back({a.channels[c], &a.data[c]});
    fs::create_directories(dir / "nanepi");
    haze::render::write_exr_channels((dir / "nanepi/frame_0000.exr").string(), a.width, a.height, all,
                                     glm::vec3(std::nanf(""), 0.f, 1.f));
    expect_one_line_error(
        run(fmt::format("denoise {} --out {}", (dir / "nanepi").string(), (dir / "dn").string())),
        "frame_0000.exr");
  }
  // With the instance switched off the volume term is the noisy one and no volume layer is written.
  auto off = run(fmt::format("denoise {} --out {} --set denoise.volume.enabled=false", (dir / "r").string(),
                             (dir / "off").string()));
  ASSERT_EQ(off.code, 0) << off.out;
  auto o = haze::render::read_exr((dir / "off/frame_0002.exr").string());
  EXPECT_EQ(std::count(o.channels.begin(), o.channels.end(), "volume_denoised.R"), 0);
  EXPECT_TRUE(nlohmann::json::parse(std::ifstream(dir / "off/stats.json"))["volume_denoise"].is_null());
  // A later frame without the volume layers the first frame has: the file is named, nothing is written.
  auto f1 = haze::render::read_exr((dir / "r/frame_0001.exr").string());
  std::vector<std::pair<std::string, const std::vector<float>*>> kept;
  for (size_t c = 0; c < f1.channels.size(); ++c)
    if (f1.channels[c].rfind("volume", 0) != 0) kept.push_back({f1.channels[c], &f1.data[c]});
  haze::render::write_exr_channels((dir / "r/frame_0001.exr").string(), f1.width, f1.height, kept);
  auto bad = run(fmt::format("denoise {} --out {}", (dir / "r").string(), (dir / "bad").string()));
  expect_one_line_error(bad, "frame_0001.exr");
  EXPECT_NE(bad.out.find("volume"), std::string::npos) << bad.out;
  EXPECT_FALSE(fs::exists(dir / "bad/frame_0000.exr"));
}

// haze compare on two hand-made EXRs, on sequences, and its bad inputs.
TEST_F(Cli, CompareImagesAndSequences) {
  auto exr = [&](const std::string& name, std::vector<float> v, int w = 2) {
    std::vector<float> zero(v.size(), 0.f);
    std::string p = (dir / name).string();
    haze::render::write_exr_channels(p, w, int(v.size()) / w,
                                     {{"R", &zero}, {"G", &zero}, {"B", &zero}, {"volume.Y", &v}});
    return p;
  };
  std::string ref = exr("ref.exr", {1.f, 0.f}), test = exr("test.exr", {1.1f, 0.1f});
  auto r = run(fmt::format("compare {} {} --layer volume --json", ref, test));
  ASSERT_EQ(r.code, 0) << r.out;
  auto j = nlohmann::json::parse(r.out);
  EXPECT_NEAR(j["mean"]["relmse"].get<double>(), (0.01 / 1.01 + 1.0) / 2, 1e-6);
  EXPECT_NEAR(j["mean"]["psnr"].get<double>(), 20.0, 1e-4);
  auto text = run(fmt::format("compare {} {}", ref, test));
  ASSERT_EQ(text.code, 0) << text.out;
  EXPECT_NE(text.out.find("PSNR inf dB"), std::string::npos) << text.out;  // R, G, B are equal
  // Channels in haze's order, not the file's alphabetical one (FLIP takes the first three as R, G, B).
  auto base = nlohmann::json::parse(run(fmt::format("compare {} {} --json", ref, test)).out);
  EXPECT_EQ(base["channels"], (nlohmann::json{"R", "G", "B"}));

  fs::create_directories(dir / "rs");
  fs::create_directories(dir / "ts");
  exr("rs/f0.exr", {1.f, 0.f});
  exr("rs/f1.exr", {2.f, 0.f});
  exr("ts/f0.exr", {1.f, 0.f});
  exr("ts/f1.exr", {2.f, 0.5f});
  auto s =
      run(fmt::format("compare {} {} --layer volume --json", (dir / "rs").string(), (dir / "ts").string()));
  ASSERT_EQ(s.code, 0) << s.out;
  auto js = nlohmann::json::parse(s.out);
  EXPECT_EQ(js["frames"].size(), 2u);
  EXPECT_NEAR(js["temporal"]["change_ratio"].get<double>(), 1.5, 1e-9);
  for (const char* k : {"flip_ldr", "flip_hdr"}) {
    EXPECT_GT(j["mean"][k].get<double>(), 0.0) << k;
    EXPECT_EQ(js["frames"][0]["metrics"][k].get<double>(), 0.0) << k;  // identical first frames
    EXPECT_GT(js["mean"][k].get<double>(), 0.0) << k;
  }

  // --flip-map: PATH.exr with flip_hdr.Y and flip_ldr.Y whose means are the reported ones, PATH.png.
  auto m = run(fmt::format("compare {} {} --layer volume --json --flip-map {}", ref, test,
                           (dir / "maps/flip").string()));
  ASSERT_EQ(m.code, 0) << m.out;
  auto jm = nlohmann::json::parse(m.out);
  auto map = haze::render::read_exr((dir / "maps/flip.exr").string());
  ASSERT_EQ(map.width, 2);
  ASSERT_EQ(map.height, 1);
  for (const char* k : {"flip_ldr", "flip_hdr"}) {
    const auto& v = map.channel(std::string(k) + ".Y");
    EXPECT_NEAR((v[0] + v[1]) / 2, jm["mean"][k].get<double>(), 1e-6) << k;
  }
  EXPECT_TRUE(fs::exists(dir / "maps/flip.png"));
  auto ms = run(fmt::format("compare {} {} --layer volume --flip-map {}", (dir / "rs").string(),
                            (dir / "ts").string(), (dir / "seqmaps").string()));
  ASSERT_EQ(ms.code, 0) << ms.out;
  EXPECT_NE(ms.out.find("FLIP LDR"), std::string::npos) << ms.out;
  for (const char* f : {"f0.exr", "f0.png", "f1.exr", "f1.png"}) {
    EXPECT_TRUE(fs::exists(dir / "seqmaps" / f)) << f;
  }

  expect_one_line_error(run(fmt::format("compare {} {}", ref, (dir / "none.exr").string())), "none.exr");
  expect_one_line_error(run(fmt::format("compare {} {} --layer denoised", ref, test)), "--layer");
  expect_one_line_error(run(fmt::format("compare {} {}", ref, exr("wide.exr", {1, 2, 3, 4}, 4))),
                        "compare images of one size");
  expect_one_line_error(run(fmt::format("compare {} {} --layer volume", ref, exr("nan.exr", {NAN, 0.f}))),
                        "non-finite");
  expect_one_line_error(run(fmt::format("compare {} {}", ref, (dir / "rs").string())), "two folders");
}

TEST_F(Cli, BenchReportsRatiosAsJson) {
  // The shaft part runs only when named.
  auto r = run(fmt::format(
      "bench --json --size 16x16 --spp 1 --denoise-sizes 24x16 --guiding-size 16x12 --guiding-seeds 1 "
      "--only first_frame,passes,bvh,svgf,guiding,velocity,volume_repr,view,shafts "
      "--shafts-size 24x16 --shafts-frames 2 --shafts-reference-spp 4 --reference-dir {}",
      (dir / "refs").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  auto j = nlohmann::json::parse(r.out.substr(r.out.find('{')));
  EXPECT_GT(j["passes"]["trace"]["ratio_to_copy"].get<double>(), 0.0);
  EXPECT_GT(j["bvh"]["gpu_over_embree"].get<double>(), 0.0);
  EXPECT_GT(j["density_lookups_per_s"].get<double>(), 0.0);
  for (const char* kernel : {"5x5", "subsampled"}) {
    EXPECT_GT(j["svgf_surface"]["24x16"][kernel]["total"]["ratio_to_copy"].get<double>(), 0.0) << kernel;
    EXPECT_GT(j["svgf_surface"]["24x16"][kernel]["total"]["ratio_to_roofline"].get<double>(), 0.0) << kernel;
    EXPECT_GT(j["svgf_surface"]["24x16"][kernel]["gather_floor"]["ratio_to_copy"].get<double>(), 0.0)
        << kernel;
  }
  EXPECT_TRUE(j["summary"].contains("svgf.surface 24x16 gather floor/copy"));
  // The roofline moves 124 bytes per pixel (bench.cpp, kSvgfRooflineRead + kSvgfRooflineWritten).
  EXPECT_EQ(j["svgf_surface"]["24x16"]["roofline_bytes_per_pixel"]["read"].get<size_t>(), 96u);
  EXPECT_EQ(j["svgf_surface"]["24x16"]["roofline_bytes_per_pixel"]["written"].get<size_t>(), 28u);
  for (const auto& e : j["guiding"]["equal_time"])
    EXPECT_GT(e["relmse_ratio_unguided_over_guided"]["mean"].get<double>(), 0.0);
  for (const char* key : {"volume_denoiser", "volume_occluder"})
    for (const char* ratio :
         {"relmse_surface_motion_over_virtual_points", "relmse_backward_over_virtual_points",
          "relmse_surface_geometry_over_virtual_points"})
      EXPECT_GT(j["guiding"][key][ratio]["ratio_of_means"].get<double>(), 0.0) << key << " " << ratio;
  EXPECT_EQ(j["shafts"]["per_frame"].size(), 2u);
  EXPECT_GT(j["shafts"]["per_frame"][1]["flip_ldr"]["composite"].get<double>(), 0.0);
  EXPECT_TRUE(j["shafts"]["per_frame"][1]["sheet_contrast"].contains("accumulation_only_over_reference"));
}

// scenes/smoke.json, the demo of a drifting smoke sequence that carries its velocity, under a generated sky:
// its assets come from scripts/make_demo_assets.sh (not committed), written here beside a copy of the scene,
// and two small frames render with the velocity grids moving the volume motion vectors (frame 1), the map
// and MIS, discarding nothing. Keeps the scene, the script and the keys they use from rotting. Injected: the
// scene's velocity key removed: no velocity grid in the ledger (fails).
TEST_F(Cli, DemoSmokeSceneRendersFromGeneratedAssets) {
  fs::copy_file(fs::path(HAZE_SOURCE_DIR) / "scenes/smoke.json", dir / "smoke.json");
  const Result g = haze::test::run_command(fmt::format("HAZE={} {}/scripts/make_demo_assets.sh {}", HAZE_BIN,
                                                       HAZE_SOURCE_DIR, (dir / "assets").string()));
  ASSERT_EQ(g.code, 0) << g.out;
  const Result r = run(fmt::format("render {} --out {} --frames 0:1 --size 48x27 --spp 2",
                                   (dir / "smoke.json").string(), (dir / "out").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto st = nlohmann::json::parse(std::ifstream(dir / "out/stats.json"));
  const std::string kernels = st["kernels"].dump();
  for (const char* feature : {"ENV_MAP", "MIS", "HETERO", "SURFACES"})
    EXPECT_NE(kernels.find(feature), std::string::npos) << feature << " not in " << kernels;
  // Frame 1 moved frame 0's virtual points with the velocity grids: they are in the ledger.
  int velocity_grids = 0;
  for (const auto& e : st["memory"]["entries"])
    velocity_grids += e["name"].get<std::string>().find("velocity.grid") != std::string::npos;
  EXPECT_EQ(velocity_grids, 3);
  ASSERT_EQ(st["frames"].size(), 2u);
  for (const auto& f : st["frames"])
    for (const auto& [kind, n] : f["discarded"].items()) EXPECT_EQ(n.get<int>(), 0) << kind;
  EXPECT_TRUE(fs::exists(dir / "out/frame_0001.png"));
}

}  // namespace
