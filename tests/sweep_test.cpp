// The research workflow as a user runs it: `haze reference`, `haze sweep` (bad files fail before any run,
// expansion, sharding covers every run once, resume after a kill loses and duplicates nothing, merge) and
// `haze report` (opens in headless Chromium without script errors and shows its plots).
#include "eval/sweep.hpp"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <stb/stb_image.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "eval/reference.hpp"
#include "eval/report.hpp"
#include "haze_cli.hpp"
#include "render/output.hpp"
#include "temp_dir.hpp"

namespace {

namespace fs = std::filesystem;
using haze::test::TempDir;
using nlohmann::json;

using haze::test::Result;
using haze::test::run;

std::vector<std::string> lines(const fs::path& p) {
  std::ifstream f(p);
  std::vector<std::string> out;
  for (std::string l; std::getline(f, l);)
    if (!l.empty()) out.push_back(l);
  return out;
}

// A quick scene: bounded haze lit by a point light (no PNanoVDB in the shader variant).
const char* kScene = R"({
  "camera": {"position": [0, 1, 6], "target": [0, 1, 0], "fov_y": 40},
  "haze": {"sigma_t": 0.3, "albedo": [0.9, 0.9, 0.9], "g": 0.3, "bounded": true,
           "bounds_min": [-2, -1, -2], "bounds_max": [2, 3, 2]},
  "lights": {"points": [{"position": [0.5, 1.5, 0], "intensity": 20}],
             "environment": {"color": [0.2, 0.3, 0.4], "intensity": 1}},
  "render": {"width": 16, "height": 12, "spp": 2}
})";

// Four settings by two seeds, errors against a (quick) reference.
const char* kSweep = R"({
  "description": "equi-angular share and sample count",
  "scene": "scene.json",
  "axes": [{"path": "render.spp", "values": [1, 4]},
           {"path": "render.equiangular_probability", "values": [0, 0.5]}],
  "seeds": 2,
  "reference": {"target": 0.05, "min_spp": 16, "max_spp": 128}
})";

std::set<std::string> ids_of(const std::vector<std::string>& rows) {
  std::set<std::string> ids;
  for (const auto& l : rows) ids.insert(json::parse(l)["run"].get<std::string>());
  return ids;
}

std::set<std::string> expected_ids(const fs::path& sweep) {
  std::set<std::string> ids;
  for (const auto& r : haze::eval::expand(haze::eval::load_sweep(sweep.string()))) ids.insert(r.id);
  return ids;
}

// --- sweep files, without rendering ---------------------------------------------------------------------

TEST(SweepFile, ExpandsCartesianZipAndEachWithSeeds) {
  TempDir t("haze-sweep");
  t.write("scene.json", kScene);
  auto sp = haze::eval::load_sweep(t.write("s.json", kSweep).string());
  auto runs = haze::eval::expand(sp);
  ASSERT_EQ(runs.size(), 8u);  // 2 x 2 settings x 2 seeds; the last axis, then the seed, change fastest
  EXPECT_EQ(runs[0].settings,
            (json{{"render.spp", 1}, {"render.equiangular_probability", 0}, {"render.seed", 1}}));
  EXPECT_EQ(runs[1].settings["render.seed"], 2);
  EXPECT_EQ(runs[2].settings["render.equiangular_probability"], 0.5);
  EXPECT_EQ(runs[7].settings,
            (json{{"render.spp", 4}, {"render.equiangular_probability", 0.5}, {"render.seed", 2}}));
  std::set<std::string> ids;
  for (const auto& r : runs) ids.insert(r.id);
  EXPECT_EQ(ids.size(), runs.size());
  // Ids depend on the settings only: the same files elsewhere give the same ids.
  t.write("copy/scene.json", kScene);
  EXPECT_EQ(haze::eval::expand(haze::eval::load_sweep(t.write("copy/s.json", kSweep).string()))[5].id,
            runs[5].id);

  json zip = json::parse(kSweep);
  zip["combine"] = "zip";
  EXPECT_EQ(haze::eval::expand(haze::eval::load_sweep(t.write("z.json", zip.dump()).string())).size(), 4u);
  json each = zip;
  each["combine"] = "each";
  each["axes"][1]["values"] = {0, 0.25, 0.5};
  auto e = haze::eval::expand(haze::eval::load_sweep(t.write("e.json", each.dump()).string()));
  ASSERT_EQ(e.size(), (2u + 3u) * 2u);
  EXPECT_FALSE(e[0].settings.contains("render.equiangular_probability"));  // other axes stay at base
  json multi = json::parse(kSweep);
  multi["axes"] =
      json::parse(R"([{"paths": ["render.width", "render.height"], "values": [[8, 6], [16, 12]]}])");
  auto m = haze::eval::expand(haze::eval::load_sweep(t.write("m.json", multi.dump()).string()));
  ASSERT_EQ(m.size(), 4u);
  EXPECT_EQ(m[2].settings["render.width"], 16);
  EXPECT_EQ(m[2].settings["render.height"], 12);
}

// docs/workflow.md walks through scenes/guiding.sweep.json: its copy of the file is the shipped one.
TEST(SweepFile, WorkflowDocShowsTheShippedSweep) {
  std::ifstream doc_file(std::string(HAZE_SOURCE_DIR) + "/docs/workflow.md");
  const std::string doc((std::istreambuf_iterator<char>(doc_file)), std::istreambuf_iterator<char>());
  const size_t at = doc.find("```json\n", doc.find("## A complete example"));
  ASSERT_NE(at, std::string::npos);
  const size_t end = doc.find("```", at + 8);
  const json shown = json::parse(doc.substr(at + 8, end - at - 8));
  const json shipped =
      json::parse(std::ifstream(std::string(HAZE_SOURCE_DIR) + "/scenes/guiding.sweep.json"));
  EXPECT_EQ(shown, shipped);
  EXPECT_NO_THROW(haze::eval::load_sweep(std::string(HAZE_SOURCE_DIR) + "/scenes/guiding.sweep.json"));
}

TEST(SweepFile, ShardsCoverEveryRunExactlyOnce) {
  TempDir t("haze-sweep");
  t.write("scene.json", kScene);
  json j = json::parse(kSweep);
  j["axes"].push_back({{"path", "render.max_depth"}, {"values", {1, 2, 3}}});
  const fs::path f = t.write("s.json", j.dump());
  auto runs = haze::eval::expand(haze::eval::load_sweep(f.string()));
  ASSERT_EQ(runs.size(), 24u);
  for (int n : {1, 2, 3, 5, 7, 24, 30}) {
    std::multiset<std::string> seen;
    for (int i = 0; i < n; ++i)
      for (const auto& r : haze::eval::shard_runs(runs, haze::eval::parse_shard(fmt::format("{}/{}", i, n))))
        seen.insert(r.id);
    EXPECT_EQ(seen.size(), runs.size()) << n << " shards";
    for (const auto& r : runs) EXPECT_EQ(seen.count(r.id), 1u) << n << " shards, run " << r.index;
  }
  // The command line's --list agrees: 3 shards' listings are the runs, each once.
  std::multiset<std::string> listed;
  for (int i = 0; i < 3; ++i) {
    Result r =
        run(fmt::format("sweep {} --out {} --list --shard {}/3", f.string(), (t.path() / "o").string(), i));
    ASSERT_EQ(r.code, 0) << r.out;
    for (const auto& l : lines(t.write(fmt::format("list{}", i), r.out)))
      listed.insert(json::parse(l)["run"]);
  }
  EXPECT_EQ(listed.size(), runs.size());
  for (const auto& r : runs) EXPECT_EQ(listed.count(r.id), 1u);
  for (const char* bad : {"3/3", "-1/2", "1/0", "x", "1/2/3"})
    EXPECT_THROW(haze::eval::parse_shard(bad), haze::render::Error) << bad;
}

TEST(SweepFile, BadFilesFailBeforeAnyRun) {
  TempDir t("haze-sweep");
  t.write("scene.json", kScene);
  struct Bad {
    std::string patch, needle;
  };
  const std::vector<Bad> cases = {
      {R"({"axis": []})", "axis: unknown key"},
      {R"({"axes": [{"path": "render.spp", "values": []}]})", "axes[0].values: is empty"},
      {R"({"axes": [{"path": "render.spp", "values": 4}]})", "axes[0].values: expected an array"},
      {R"({"axes": [{"path": "render.spp", "value": [1]}]})", "axes[0].value: unknown key"},
      {R"({"axes": [{"path": "render.spp", "values": ["many"]}]})", "axes[0].values[0]"},
      {R"({"axes": [{"path": "render.sppp", "values": [1]}]})", "render.sppp: unknown key"},
      {R"({"axes": [{"path": "render.spp", "values": [0]}]})", "render.spp: must be in"},
      {R"({"axes": [{"paths": ["render.width", "render.height"], "values": [[8]]}]})", "one per path"},
      {R"({"combine": "zip", "axes": [{"path": "render.spp", "values": [1, 2]},
                                      {"path": "render.seed", "values": [1]}]})",
       "zipped axes need equal lengths"},
      {R"({"combine": "diagonal"})", "combine"},
      {R"({"seeds": "two"})", "seeds"},
      {R"({"seeds": [4000000007]})", "references' seed"},
      {R"({"frames": "3:1"})", "frames"},
      {R"({"layer": "volumes"})", "layer"},
      {R"({"reference": {"target": -1}})", "reference.target"},
      {R"({"reference": {"budget": 4}})", "reference.budget: unknown key"},
      {R"({"set": {"haze.sigma_t": "thick"}})", "haze.sigma_t"},
      {R"({"scene": "missing.json"})", "no such file"},
      {R"({"axes": [{"path": "render.spp", "values": [1]}, {"path": "render.seed", "values": [1]},
                    {"paths": ["render.width", "render.spp"], "values": [[8, 2]]}]})",
       "axes[2]: sets render.spp, which axes[0] sets too"},
      {R"({"axes": [{"path": "lights.points[0].intensity", "values": [1]},
                    {"path": "lights.points.0.intensity", "values": [2]}]})",
       "axes[1]: sets lights.points.0.intensity, which axes[0] sets too"},
  };
  for (const auto& c : cases) {
    json j = json::parse(kSweep);
    j.merge_patch(json::parse(c.patch));
    const fs::path f = t.write("bad.json", j.dump());
    const fs::path out = t.path() / "out";
    fs::remove_all(out);
    Result r = run(fmt::format("sweep {} --out {}", f.string(), out.string()));
    EXPECT_NE(r.code, 0) << c.patch;
    EXPECT_NE(r.out.find("haze: error: "), std::string::npos) << r.out;
    EXPECT_NE(r.out.find(c.needle), std::string::npos) << "expected '" << c.needle << "' in: " << r.out;
    EXPECT_NE(r.out.find("bad.json"), std::string::npos) << r.out;
    EXPECT_FALSE(fs::exists(out / "results.jsonl")) << c.patch;  // nothing ran
    EXPECT_FALSE(fs::exists(out / "references")) << c.patch;
  }
  Result r = run(fmt::format("sweep {} --out {}", t.write("bad.json", "{\"scene\": ").string(),
                             (t.path() / "out").string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("malformed JSON"), std::string::npos) << r.out;
  // A key given twice (the JSON library would keep the last one silently).
  std::string dup = kSweep;  // it has "seeds": 2
  dup.insert(dup.find('{') + 1, "\"seeds\": 1, ");
  r = run(fmt::format("sweep {} --out {}", t.write("bad.json", dup).string(), (t.path() / "out").string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("bad.json: seeds: the key appears twice"), std::string::npos) << r.out;
}

// A procedural key of the wrong type fails before any run (the scene reader leaves procedural specs to
// vdb/), names the sweep file, and does not claim the folder: the corrected sweep then runs there.
TEST(SweepFile, FailedSweepDoesNotBlockItsFolder) {
  TempDir t("haze-sweep");
  t.write("scene.json", R"({
    "camera": {"position": [0, 0, 4], "target": [0, 0, 0]},
    "media": [{"procedural": {"kind": "sphere", "voxel_size": 0.2, "center": [0, 0, 0], "size": [1.6, 1.6, 1.6]}}],
    "lights": {"sun": {"direction": [0, 1, 0]}},
    "render": {"width": 8, "height": 8, "spp": 1}
  })");
  auto sweep = [&](const std::string& voxel) {
    return t
        .write("s.json",
               fmt::format(R"({{"scene": "scene.json", "set": {{"media.0.procedural.voxel_size": {}}},
        "axes": [{{"path": "render.spp", "values": [1, 2]}}], "reference": false}})",
                           voxel))
        .string();
  };
  const std::string out = (t.path() / "out").string();
  Result r = run(fmt::format("sweep {} --out {}", sweep("\"x\""), out));
  EXPECT_NE(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("s.json: run 0"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("media[0].procedural: key 'voxel_size'"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(fs::path(out) / "results.jsonl"));
  // The same folder takes the corrected sweep.
  r = run(fmt::format("sweep {} --out {}", sweep("0.2"), out));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(lines(fs::path(out) / "results.jsonl").size(), 2u);
}

TEST(SweepFile, TornLastRowIsDroppedAndCsvHasEveryColumn) {
  TempDir t("haze-sweep");
  json row = {{"run", "a"},
              {"index", 0},
              {"settings", {{"render.spp", 4}}},
              {"frames", "0:0"},
              {"samples", 4},
              {"time", {{"gpu_ms_per_frame", 2.5}}},
              {"memory", {{"total", 2e6}, {"peak", 3e6}, {"per_category", {{"outputs", 1e6}}}}},
              {"passes", {{"trace", {{"ms_per_frame", 2.0}}}}},
              {"metrics", {{"relmse", 0.25}}},
              {"nonfinite", 0}};
  const fs::path p = t.write("results.jsonl", row.dump() + "\n" + row.dump().substr(0, 40));
  auto rows = haze::eval::read_results(p.string());
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(lines(p).size(), 1u);  // rewritten without the torn line
  std::string csv = haze::eval::results_csv(rows);
  EXPECT_EQ(csv,
            "run,index,frames,samples,render.spp,gpu_ms_per_frame,memory_mb,memory_peak_mb,relmse,nonfinite,"
            "pass_trace_ms,mem_outputs_mb\na,0,0:0,4,4,2.5,2.0,3.0,0.25,0,2.0,1.0\n");
  t.write("mid.jsonl", row.dump() + "\nnot json\n" + row.dump() + "\n");
  EXPECT_THROW(haze::eval::read_results((t.path() / "mid.jsonl").string()), haze::render::Error);
}

TEST(SweepFile, CountsNonFiniteValuesInEveryLayer) {
  haze::render::Image img;
  img.width = 2;
  img.height = 1;
  img.data.assign(2 * haze::glsl::OUT_STRIDE, 0.5f);
  img.gbuffer.assign(2 * haze::glsl::G_STRIDE, 0.f);
  EXPECT_EQ(haze::eval::count_nonfinite(img), 0u);
  // Each value, wherever it is, is found (in every layer that reads it).
  for (size_t i : {size_t(haze::glsl::OUT_STRIDE + haze::glsl::OUT_VOL + 1), size_t(haze::glsl::OUT_VAR)}) {
    auto bad = img;
    bad.data[i] = NAN;
    EXPECT_GE(haze::eval::count_nonfinite(bad), 1u) << i;
  }
  auto bad = img;
  bad.gbuffer[haze::glsl::G_MOTION] = -INFINITY;
  EXPECT_GE(haze::eval::count_nonfinite(bad), 1u);
}

// The equal-time table on constructed results: two settings whose error falls as 1/time (B twice A's error
// at equal time for seed 1, 2.2 times for seed 2) over a spp axis, and a third whose times overlap neither.
TEST(Report, EqualTimeTableOnConstructedResults) {
  auto row = [](bool guided, int spp, int seed, double ms, double relmse) {
    json settings = {{"guiding.enabled", guided},
                     {"guiding.probability", 0.5},
                     {"render.spp", spp},
                     {"render.seed", seed}};
    return json{{"run", fmt::format("{}-{}-{}", guided, spp, seed)},
                {"index", 0},
                {"settings", settings},
                {"frames", "0:0"},
                {"samples", spp},
                {"time", {{"gpu_ms_per_frame", ms}}},
                {"passes", {{"trace", {{"ms_per_frame", ms}}}}},
                {"memory", {{"total", 1e6}, {"peak", 1e6}, {"per_category", {{"outputs", 1e6}}}}},
                {"metrics", {{"relmse", relmse}}},
                {"nonfinite", 0},
                {"images", json::array()},
                {"device", "constructed"}};
  };
  std::vector<json> rows;
  for (int seed : {1, 2})
    for (int spp : {1, 4, 16}) {
      const double ta = 10.0 * spp, tb = 12.0 * spp;
      rows.push_back(row(true, spp, seed, ta, 1.0 / ta));                       // A: guided
      rows.push_back(row(false, spp, seed, tb, (seed == 1 ? 2.0 : 2.2) / tb));  // B: unguided
    }
  const json et = haze::eval::equal_time_table(rows, "relmse");
  ASSERT_TRUE(et.is_object()) << et.dump();
  EXPECT_EQ(et["cost_axis"], "render.spp");
  EXPECT_EQ(et["curves"], json({"guiding.enabled=true, guiding.probability=0.5", "guiding.enabled=false"}));
  ASSERT_EQ(et["budgets"].size(), 3u);
  const double budgets[] = {12, std::sqrt(12.0 * 160), 160};  // inside both curves' ranges
  for (size_t i = 0; i < 3; ++i) {
    const json& b = et["budgets"][i];
    EXPECT_NEAR(b["ms"].get<double>(), budgets[i], 1e-9);
    EXPECT_EQ(b["winner"], "guiding.enabled=true, guiding.probability=0.5");
    const json& a = b["rows"][0];
    const json& u = b["rows"][1];
    EXPECT_NEAR(a["error"].get<double>(), 1.0 / budgets[i], 1e-9);  // a power law interpolates exactly
    EXPECT_DOUBLE_EQ(a["ratio"].get<double>(), 1.0);
    EXPECT_NEAR(u["ratio"].get<double>(), 2.1, 1e-9);  // of the seed-mean curves
    EXPECT_NEAR(u["ratio_mean"].get<double>(), 2.1, 1e-9);
    EXPECT_NEAR(u["ratio_sd"].get<double>(), 0.2 / std::sqrt(2.0), 1e-9);
    EXPECT_EQ(u["seeds"], 2);
    EXPECT_EQ(u["short"], "enabled=false");  // guiding off has no probability
  }
  // Settings whose times do not overlap get no budget, and a note that says why.
  std::vector<json> apart = {row(true, 1, 1, 1, 1), row(true, 4, 1, 2, 0.5), row(false, 1, 1, 10, 1),
                             row(false, 4, 1, 20, 0.5)};
  const json none = haze::eval::equal_time_table(apart, "relmse");
  EXPECT_TRUE(none["budgets"].empty());
  EXPECT_NE(none["note"].get<std::string>().find("do not overlap"), std::string::npos);
  EXPECT_TRUE(haze::eval::equal_time_table({rows[0], rows[2]}, "relmse").is_null());  // one curve

  // Through `haze report`: the summary opens the page with the answer, and the table is there.
  TempDir t("haze-report");
  rows[0]["reference_notes"] = {"reference frame 0 did not converge: error 0.103 at quantile 0.99"};
  std::string text;
  for (const auto& r : rows) text += r.dump() + "\n";
  t.write("out/results.jsonl", text);
  t.write("out/sweep.json", R"({"scene": "demo.json", "reference": {"target": 0.05, "quantile": 0.95,
    "min_spp": 64, "max_spp": 2048}, "layer": ""})");
  Result r = run(fmt::format("report {}", (t.path() / "out").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  std::ifstream f(t.path() / "out/report.html");
  const std::string html((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const size_t summary = html.find("<h2>Summary</h2>");
  ASSERT_NE(summary, std::string::npos);
  EXPECT_LT(summary, html.find("<img"));
  EXPECT_NE(html.find("At equal time, 12 ms per frame: guiding.enabled=true, guiding.probability=0.5 wins "
                      "with relmse 0.0833; the others' relmse is higher by: enabled=false 2.10x (per seed "
                      "2.10 ± 0.14, 2 seeds)."),
            std::string::npos)
      << html.substr(summary, 1500);
  EXPECT_NE(html.find("<table id=\"equal-time\">"), std::string::npos);
  EXPECT_NE(html.find("Caution: 1 reference frame did not converge"), std::string::npos);
  EXPECT_EQ(html.find("two different images"), std::string::npos);
  // Rows from before results named their layers compared the sweep's layer with the reference's R, G, B.
  t.write("out/sweep.json", R"({"scene": "demo.json", "reference": {"target": 0.05, "quantile": 0.95,
    "min_spp": 64, "max_spp": 2048}, "layer": "volume"})");
  const json data = haze::eval::report_data((t.path() / "out").string(), haze::eval::ReportOptions{});
  EXPECT_EQ(data["layers"], json({{"test", "volume"}, {"reference", ""}}));
  EXPECT_NE(haze::eval::report_summary(data)[1].find("Caution: these rows compared test layer volume, "
                                                     "reference R, G, B, two different images"),
            std::string::npos);
}

// --- rendering ------------------------------------------------------------------------------------------

TEST(Reference, ConvergesToItsTargetAndIsCached) {
  TempDir t("haze-ref");
  const fs::path scene = t.write("scene.json", kScene);
  const std::string out = (t.path() / "ref").string();
  Result r = run(fmt::format("reference {} --out {} --target 0.05 --quantile 0.9 --min-spp 8 --max-spp 4096",
                             scene.string(), out));
  ASSERT_EQ(r.code, 0) << r.out;
  json info = json::parse(std::ifstream(fs::path(out) / "reference.json"));
  const json& f0 = info["frames"]["0"];
  EXPECT_TRUE(f0["converged"].get<bool>()) << info.dump();
  EXPECT_LE(f0["error_quantile"].get<double>(), 0.05);
  // The stored image has its variance, and its errors agree with what reference.json says.
  haze::render::ExrImage img = haze::render::read_exr(haze::eval::reference_frame_path(out, 0));
  const auto &R = img.channel("R"), &V = img.channel("variance.R");
  const double n = f0["spp"].get<double>();
  std::vector<double> e;
  for (size_t p = 0; p < R.size(); ++p) e.push_back(std::sqrt(V[p] / n / (R[p] * R[p] + 0.01)));
  std::sort(e.begin(), e.end());
  EXPECT_LE(e[size_t(std::ceil(0.9 * e.size())) - 1], f0["error_quantile"].get<double>() + 1e-6);
  // A second call finds it; another scene in the same folder is refused; estimator settings share the key.
  r = run(fmt::format("reference {} --out {} --target 0.05 --quantile 0.9 --min-spp 8 --max-spp 4096",
                      scene.string(), out));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("up to date"), std::string::npos) << r.out;
  r = run(
      fmt::format("reference {} --out {} --target 0.05 --quantile 0.9 --min-spp 8 --max-spp 4096 --set "
                  "render.spp=64 --set render.equiangular_probability=0.1 --set guiding.enabled=true --set "
                  "render.walk_splits=2 --set render.sun_walk_probability=0.3",
                  scene.string(), out));
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("up to date"), std::string::npos) << r.out;
  r = run(fmt::format("reference {} --out {} --set haze.sigma_t=0.5", scene.string(), out));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("holds the reference of another scene"), std::string::npos) << r.out;
  // A PNG preview beside the EXR; rendered guided (the scene has a medium and a light).
  int w = 0, h = 0, channels = 0;
  EXPECT_TRUE(stbi_info(haze::eval::reference_png_path(out, 0).c_str(), &w, &h, &channels));
  EXPECT_EQ(channels, 3);
  EXPECT_EQ(info["frames"]["0"].count("note"), 0u);
  EXPECT_NE(info["frames"]["0"]["features"].get<std::string>().find("guiding"), std::string::npos)
      << info["frames"]["0"];
}

// A budget too small for the target: the reference says so, with its figures, in the terminal and in
// reference.json; the checks aim at the target instead of doubling past it.
TEST(Reference, SaysWhenItDidNotConverge) {
  TempDir t("haze-ref");
  const fs::path scene = t.write("scene.json", kScene);
  const std::string out = (t.path() / "ref").string();
  Result r =
      run(fmt::format("reference {} --out {} --target 0.001 --min-spp 4 --max-spp 16", scene.string(), out));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("note: reference frame 0 did not converge: error "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("after 16 spp"), std::string::npos) << r.out;
  json info = json::parse(std::ifstream(fs::path(out) / "reference.json"));
  EXPECT_FALSE(info["frames"]["0"]["converged"].get<bool>());
  EXPECT_NE(info["frames"]["0"]["note"].get<std::string>().find("raise max_spp"), std::string::npos);
  haze::eval::ReferenceOptions o;
  o.target = 0.05;
  o.max_spp = 10000;
  EXPECT_EQ(haze::eval::next_check_spp(64, 0.1, o), 256);      // 4x at most
  EXPECT_EQ(haze::eval::next_check_spp(64, 0.06, o), 102);     // 1.1 * 64 * 1.44 = 101.4
  EXPECT_EQ(haze::eval::next_check_spp(64, 0.051, o), 74);     // close: 10% over
  EXPECT_EQ(haze::eval::next_check_spp(5000, 0.1, o), 10000);  // the budget caps it
  EXPECT_EQ(haze::eval::next_check_spp(64, INFINITY, o), 256);
  EXPECT_EQ(haze::eval::next_check_spp(64, NAN, o), 256);
}

// A layer is compared with the same layer of the reference: the sweep's figures are those of `haze compare
// --layer` on the run's saved frame and its reference (which fail if the sweep read another layer of either
// side), the row names both layers, and a reference holds the denoised layers a denoised run is compared on.
TEST(Sweep, ComparesALayerWithTheSameLayerOfTheReference) {
  TempDir t("haze-sweep");
  json scene = json::parse(kScene);
  scene["surfaces"] =
      json::parse(R"([{"mesh": {"kind": "plane", "size": [20, 20]}, "albedo": [0.7, 0.7, 0.7]}])");
  t.write("scene.json", scene.dump());
  const fs::path sweep = t.write("s.json", R"({"scene": "scene.json", "seeds": [3], "layer": "volume",
    "reference": {"target": 0.1, "min_spp": 16, "max_spp": 64}})");
  const fs::path out = t.path() / "out";
  Result r = run(fmt::format("sweep {} --out {}", sweep.string(), out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto rows = lines(out / "results.jsonl");
  ASSERT_EQ(rows.size(), 1u);
  const json row = json::parse(rows[0]);
  EXPECT_EQ(row["layers"], json({{"test", "volume"}, {"reference", "volume"}}));
  EXPECT_NE(r.out.find("(+ references: "), std::string::npos) << r.out;  // apart from the runs' ETA
  const std::string test_exr = (out / row["images"][0].get<std::string>()).string();
  const std::string ref_exr =
      haze::eval::reference_frame_path((out / row["reference"].get<std::string>()).string(), 0);
  for (const char* layer : {"volume", "", "denoised", "volume_denoised"}) {
    r = run(fmt::format("compare {} {} --json{}", ref_exr, test_exr,
                        *layer ? std::string(" --layer ") + layer : ""));
    ASSERT_EQ(r.code, 0) << layer << ": " << r.out;
    const json c = json::parse(r.out);
    EXPECT_EQ(c["layers"], json({{"test", layer}, {"reference", layer}}));
    const double relmse = c["mean"]["relmse"].get<double>();
    if (std::string(layer) == "volume") {
      EXPECT_NEAR(row["metrics"]["relmse"].get<double>(), relmse, 1e-6 * relmse) << r.out;
    } else if (std::string(layer) == "") {  // the plane makes R, G, B another image than the volume term
      EXPECT_GT(std::abs(row["metrics"]["relmse"].get<double>() - relmse), 1e-3 * relmse) << r.out;
    }
  }
  r = run(fmt::format("compare {} {} --layer volume", ref_exr, test_exr));
  EXPECT_NE(r.out.find("test layer volume, reference layer volume"), std::string::npos) << r.out;
  // The reference's denoised stand-in is its noisy composite.
  const auto ref = haze::render::read_exr(ref_exr);
  EXPECT_EQ(ref.channel("denoised.G"), ref.channel("G"));
  EXPECT_EQ(ref.channel("volume_denoised.R"), ref.channel("volume.R"));
}

// render.time_budget_s as an axis: each run samples until its budget is spent, and says how many it took.
TEST(Sweep, TimeBudgetAxis) {
  TempDir t("haze-sweep");
  t.write("scene.json", kScene);
  const fs::path sweep = t.write("s.json", R"({"scene": "scene.json", "seeds": [5], "save_images": "none",
    "axes": [{"path": "render.time_budget_s", "values": [0.02, 0.3]}]})");
  Result r = run(fmt::format("sweep {} --out {}", sweep.string(), (t.path() / "out").string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto rows = lines(t.path() / "out/results.jsonl");
  ASSERT_EQ(rows.size(), 2u);
  const json a = json::parse(rows[0]), b = json::parse(rows[1]);
  EXPECT_GE(a["samples"].get<double>(), 1);
  EXPECT_GT(b["samples"].get<double>(), 3 * a["samples"].get<double>()) << rows[0] << rows[1];
  EXPECT_GE(b["time"]["render_s"].get<double>(), 0.3);
}

// Kills a sweep after its first finished run, tears the last row as a kill mid-write would, and runs the
// same command again: every run is there once, and the rows written before the kill are unchanged.
TEST(Sweep, ResumesAfterAKillWithoutLostOrDuplicateRows) {
  TempDir t("haze-sweep");
  t.write("scene.json", kScene);
  json j = json::parse(kSweep);
  j["seeds"] = 3;
  j["axes"][0]["values"] = {2, 8};
  const fs::path sweep = t.write("s.json", j.dump());
  const fs::path out = t.path() / "out";
  const size_t total = 12;
  pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    std::freopen("/dev/null", "w", stderr);
    execl(HAZE_BIN, HAZE_BIN, "sweep", sweep.c_str(), "--out", out.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  const fs::path jsonl = out / "results.jsonl";
  auto until = std::chrono::steady_clock::now() + std::chrono::minutes(5);
  while (lines(jsonl).empty() && std::chrono::steady_clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  kill(pid, SIGKILL);
  int status = 0;
  waitpid(pid, &status, 0);
  const std::vector<std::string> before = lines(jsonl);
  ASSERT_GE(before.size(), 1u);
  ASSERT_LT(before.size(), total) << "the sweep finished before the kill; the test needs slower runs";
  std::ofstream(jsonl, std::ios::app) << before.back().substr(0, before.back().size() / 2);  // torn row

  Result r = run(fmt::format("sweep {} --out {}", sweep.string(), out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find(fmt::format("{} finished before", before.size())), std::string::npos) << r.out;
  const std::vector<std::string> after = lines(jsonl);
  ASSERT_EQ(after.size(), total);
  EXPECT_EQ(ids_of(after), expected_ids(sweep));
  for (size_t i = 0; i < before.size(); ++i) EXPECT_EQ(after[i], before[i]);
  EXPECT_EQ(lines(out / "results.csv").size(), total + 1);
  // Nothing left to do: a third call renders nothing and changes nothing.
  r = run(fmt::format("sweep {} --out {}", sweep.string(), out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("0 to do"), std::string::npos) << r.out;
  EXPECT_EQ(lines(jsonl), after);
  // A different sweep file is refused in this folder.
  j["seeds"] = 4;
  r = run(fmt::format("sweep {} --out {}", t.write("s2.json", j.dump()).string(), out.string()));
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("different sweep"), std::string::npos) << r.out;
}

// Two shards into one folder, merged; every row's figures are there; the report opens in Chromium.
TEST(Sweep, ShardsMergeAndReportOpensInChromium) {
  TempDir t("haze-sweep");
  t.write("scene.json", kScene);
  const fs::path sweep = t.write("s.json", kSweep);
  const fs::path out = t.path() / "out";
  Result r = run(fmt::format("sweep {} --out {} --shard 1/2", sweep.string(), out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  r = run(fmt::format("sweep {} --out {} --merge", sweep.string(), out.string()));
  EXPECT_NE(r.code, 0);  // shard 0 is missing
  EXPECT_NE(r.out.find("merged 4 of 8 runs; 4 missing"), std::string::npos) << r.out;
  r = run(fmt::format("sweep {} --out {} --shard 0/2", sweep.string(), out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  r = run(fmt::format("sweep {} --out {} --merge", sweep.string(), out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto rows = lines(out / "results.jsonl");
  ASSERT_EQ(rows.size(), 8u);
  EXPECT_EQ(ids_of(rows), expected_ids(sweep));
  for (const auto& l : rows) {
    json row = json::parse(l);
    for (const char* m : {"relmse", "smape", "mse", "psnr", "flip_ldr", "flip_hdr"})
      EXPECT_TRUE(row["metrics"].contains(m)) << m << " " << l;
    EXPECT_GT(row["time"]["gpu_ms_per_frame"].get<double>(), 0);
    EXPECT_GT(row["passes"]["trace"]["ms_per_frame"].get<double>(), 0);
    EXPECT_GT(row["memory"]["per_category"]["per-frame temporaries"].get<double>(), 0);
    EXPECT_EQ(row["nonfinite"], 0);
    ASSERT_EQ(row["images"].size(), 1u);
    EXPECT_TRUE(fs::exists(out / row["images"][0].get<std::string>())) << l;  // paths relative to out
  }
  // More samples, less error: the means over seeds and equi-angular settings.
  double e1 = 0, e4 = 0;
  for (const auto& l : rows) {
    json row = json::parse(l);
    (row["settings"]["render.spp"] == 1 ? e1 : e4) += row["metrics"]["relmse"].get<double>();
  }
  EXPECT_LT(e4, e1);

  r = run(fmt::format("report {}", out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const fs::path html = out / "report.html";
  ASSERT_TRUE(fs::exists(html));
  for (const char* png : {"pareto.png", "passes.png", "memory.png", "images.png"})
    EXPECT_GT(fs::file_size(out / "report_figures" / png), 1000u) << png;
  std::ifstream html_file(html);
  std::string text((std::istreambuf_iterator<char>(html_file)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text.find("src=\"report_figures"), std::string::npos) << "figures must be embedded";
  // Headless Chromium: the page's own script records loaded plots and any script error in the DOM.
  const fs::path profile = t.path() / "chromium-profile";
  std::string cmd = fmt::format(
      "timeout 120 chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
      "--disable-background-networking --disable-component-update --disable-sync --user-data-dir={} "
      "--enable-logging=stderr --v=0 --virtual-time-budget=5000 --dump-dom file://{} 2>{}",
      profile.string(), fs::absolute(html).string(), (t.path() / "chromium.log").string());
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string dom;
  std::array<char, 4096> buf{};
  while (size_t n = fread(buf.data(), 1, buf.size(), p)) dom.append(buf.data(), n);
  ASSERT_EQ(pclose(p), 0) << "chromium failed (installed by scripts/setup.sh?)";
  EXPECT_NE(dom.find("data-plots-loaded=\"4/4\""), std::string::npos) << dom.substr(0, 400);
  EXPECT_EQ(dom.find("data-script-errors=\""), std::string::npos);
  std::ifstream log(t.path() / "chromium.log");
  std::string log_text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  EXPECT_EQ(log_text.find("Uncaught"), std::string::npos) << log_text;
}

// scenes/stability.sweep.json: the extremes of every valid input, one at a time, over two frames.
TEST(Sweep, StabilitySweepStaysFinite) {
  TempDir t("haze-sweep");
  const fs::path out = t.path() / "out";
  Result r = run(fmt::format("sweep {}/scenes/stability.sweep.json --out {}", HAZE_SOURCE_DIR, out.string()));
  ASSERT_EQ(r.code, 0) << r.out;
  const auto rows = lines(out / "results.jsonl");
  EXPECT_EQ(rows.size(), haze::eval::expand(haze::eval::load_sweep(std::string(HAZE_SOURCE_DIR) +
                                                                   "/scenes/stability.sweep.json"))
                             .size());
  for (const auto& l : rows) {
    json row = json::parse(l);
    EXPECT_EQ(row["nonfinite"], 0) << row["settings"].dump();
    // Nothing was dropped to stay finite, nor cut by the step cap or a majorant violation.
    EXPECT_EQ(row["discarded"], json({{"non_finite", 0}, {"step_cap", 0}, {"majorant", 0}}))
        << row["settings"].dump();
    EXPECT_EQ(row["frames"], "0:1");
  }
}

}  // namespace
