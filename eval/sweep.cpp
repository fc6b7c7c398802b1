#include "eval/sweep.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "eval/compare.hpp"
#include "eval/metrics.hpp"
#include "reflect/params.hpp"
#include "render/output.hpp"
#include "render/run.hpp"
#include "scene/animation.hpp"
#include "surfaces/scene_geometry.hpp"
#include "vdb/vdb.h"

namespace haze::eval {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

const std::vector<std::string> kKeys = {"scene",          "set",         "axes",       "combine",
                                        "seeds",          "frames",      "reference",  "layer",
                                        "require_finite", "save_images", "description"};

// A scene error about an override reads "(in --set path=v)"; in a sweep the override came from the file.
std::string from_sweep(std::string msg) {
  for (const char* s : {"(in --set ", "(value from --set "}) {
    size_t at = msg.find(s);
    if (at != std::string::npos) msg.replace(at, std::string(s).size(), "(from ");
  }
  return msg;
}

std::string assignment(const std::string& path, const json& value) {
  return path + "=" + value.dump();
}

// The axes' values of one run: axis index -> value index (absent axes stay at base).
using Pick = std::vector<std::pair<size_t, size_t>>;

}  // namespace

SweepSpec load_sweep(const std::string& path, const std::vector<std::string>& cli_set) {
  SweepSpec sp;
  sp.file = path;
  std::ifstream in(path);
  if (!in) throw render::Error(fmt::format("cannot open sweep file {}; check the path", path));
  std::stringstream text;
  text << in.rdbuf();
  json j;
  try {
    j = json::parse(text.str(), nullptr, true, /*ignore_comments=*/true);
  } catch (const json::exception& e) {
    std::string what = e.what();
    if (auto b = what.find("] "); b != std::string::npos) what = what.substr(b + 2);
    throw render::Error(fmt::format("{}: malformed JSON: {}; fix the syntax", path, what));
  }
  if (std::string dup = reflection::duplicate_key(text.str()); !dup.empty())
    throw render::Error(fmt::format("{}: {}: the key appears twice in one object; keep one", path, dup));
  auto fail = [&](const std::string& key, const std::string& why) {
    throw render::Error(fmt::format("{}: {}: {}", path, key, why));
  };
  if (!j.is_object()) fail("(top)", "expected an object with \"scene\" and \"axes\"");
  for (const auto& [k, v] : j.items())
    if (std::find(kKeys.begin(), kKeys.end(), k) == kKeys.end())
      fail(k, fmt::format("unknown key; the keys are {}", fmt::join(kKeys, ", ")));

  if (!j.contains("scene") || !j["scene"].is_string() || j["scene"].get<std::string>().empty())
    fail("scene",
         "expected the base scene's path (relative to the sweep file), e.g. \"scene\": \"demo.json\"");
  fs::path scene = j["scene"].get<std::string>();
  if (scene.is_relative()) scene = fs::absolute(path).parent_path() / scene;
  sp.scene = scene.lexically_normal().string();
  if (!fs::is_regular_file(sp.scene)) fail("scene", fmt::format("no such file: {}", sp.scene));

  if (j.contains("set")) {
    if (!j["set"].is_object()) fail("set", "expected an object {\"dotted.path\": value, ...}");
    for (const auto& [k, v] : j["set"].items()) sp.set.push_back(assignment(k, v));
  }
  for (const auto& a : cli_set) sp.set.push_back(a);

  if (j.contains("axes")) {
    if (!j["axes"].is_array()) fail("axes", "expected an array of {\"path\": ..., \"values\": [...]}");
    for (size_t i = 0; i < j["axes"].size(); ++i) {
      const json& a = j["axes"][i];
      const std::string key = fmt::format("axes[{}]", i);
      if (!a.is_object()) fail(key, "expected {\"path\": \"dotted.path\", \"values\": [...]}");
      for (const auto& [k, v] : a.items())
        if (k != "path" && k != "paths" && k != "values")
          fail(key + "." + k, "unknown key; an axis has \"path\" (or \"paths\") and \"values\"");
      Axis ax;
      if (a.contains("path") == a.contains("paths")) fail(key, "needs exactly one of \"path\" and \"paths\"");
      if (a.contains("path")) {
        if (!a["path"].is_string() || a["path"].get<std::string>().empty())
          fail(key + ".path", "expected a dotted path string, e.g. \"render.spp\"");
        ax.paths = {a["path"].get<std::string>()};
      } else {
        if (!a["paths"].is_array() || a["paths"].empty())
          fail(key + ".paths", "expected a non-empty array of paths");
        for (const auto& p : a["paths"]) {
          if (!p.is_string() || p.get<std::string>().empty())
            fail(key + ".paths", "expected dotted path strings");
          ax.paths.push_back(p.get<std::string>());
        }
      }
      if (!a.contains("values") || !a["values"].is_array())
        fail(key + ".values", "expected an array of values");
      if (a["values"].empty()) fail(key + ".values", "is empty; give at least one value");
      for (size_t v = 0; v < a["values"].size(); ++v) {
        const json& val = a["values"][v];
        if (ax.paths.size() > 1 && (!val.is_array() || val.size() != ax.paths.size()))
          fail(fmt::format("{}.values[{}]", key, v),
               fmt::format("expected an array of {} values, one per path", ax.paths.size()));
        if (val.is_null()) fail(fmt::format("{}.values[{}]", key, v), "null is not a value");
        ax.values.push_back(val);
      }
      sp.axes.push_back(std::move(ax));
    }
  }
  // One axis per path: two would set the same value twice, and the last would win without a word.
  std::map<std::string, std::string> axis_of;  // normalised path -> the axis that has it
  for (size_t i = 0; i < sp.axes.size(); ++i)
    for (const std::string& p : sp.axes[i].paths) {
      std::vector<std::string> segs;
      if (!reflection::detail::split_path(p, segs).empty()) continue;  // check_runs names a bad path
      const std::string key = fmt::format("{}", fmt::join(segs, "."));
      const std::string here = fmt::format("axes[{}]", i);
      if (auto [it, fresh] = axis_of.try_emplace(key, here); !fresh)
        fail(here, fmt::format("sets {}, which {} sets too; give each path one axis", p, it->second));
    }
  if (j.contains("combine")) {
    if (!j["combine"].is_string()) fail("combine", "expected \"cartesian\", \"zip\" or \"each\"");
    sp.combine = j["combine"].get<std::string>();
    if (sp.combine != "cartesian" && sp.combine != "zip" && sp.combine != "each")
      fail("combine", fmt::format("\"{}\" is not one of cartesian, zip, each", sp.combine));
  }
  if (sp.combine == "zip")
    for (size_t i = 1; i < sp.axes.size(); ++i)
      if (sp.axes[i].values.size() != sp.axes[0].values.size())
        fail(fmt::format("axes[{}].values", i),
             fmt::format("has {} values but axes[0] has {}; zipped axes need equal lengths",
                         sp.axes[i].values.size(), sp.axes[0].values.size()));
  if (j.contains("seeds")) {
    const json& s = j["seeds"];
    auto seed_ok = [&](const json& v) {
      if (!v.is_number_integer() || v.get<int64_t>() < 0 || v.get<int64_t>() > int64_t(UINT32_MAX))
        fail("seeds", fmt::format("expected whole numbers in [0, {}], got {}", UINT32_MAX, v.dump()));
      if (uint32_t(v.get<int64_t>()) == kReferenceSeed)
        fail("seeds", fmt::format("{} is the references' seed; choose another", kReferenceSeed));
      return uint32_t(v.get<int64_t>());
    };
    if (s.is_number_integer()) {
      if (s.get<int64_t>() < 1 || s.get<int64_t>() > 100000) fail("seeds", "a count must be in [1, 100000]");
      for (int64_t k = 1; k <= s.get<int64_t>(); ++k) sp.seeds.push_back(uint32_t(k));
    } else if (s.is_array() && !s.empty()) {
      for (const auto& v : s) sp.seeds.push_back(seed_ok(v));
      if (std::set<uint32_t>(sp.seeds.begin(), sp.seeds.end()).size() != sp.seeds.size())
        fail("seeds", "lists a seed twice");
    } else {
      fail("seeds", "expected a count (seeds 1..N) or a non-empty array of seeds");
    }
  }
  if (j.contains("frames")) {
    if (!j["frames"].is_string()) fail("frames", "expected \"A:B\" or \"A\"");
    sp.frames = j["frames"].get<std::string>();
    try {
      scene::parse_frames(sp.frames);
    } catch (const std::exception& e) {
      fail("frames", e.what());
    }
  }
  if (j.contains("reference") && !(j["reference"].is_boolean() && !j["reference"].get<bool>())) {
    sp.reference = reference_options_from_json(j["reference"].is_boolean() ? json::object() : j["reference"],
                                               path + ": reference");
  }
  if (j.contains("layer")) {
    if (!j["layer"].is_string()) fail("layer", "expected an EXR layer name, e.g. \"denoised\", or \"\"");
    sp.layer = j["layer"].get<std::string>();
    bool known = false;
    for (const auto& l : render::exr_layers()) known |= l.name == sp.layer && l.channels.size() == 3;
    if (!known)
      fail("layer", fmt::format("\"{}\" is not an RGB layer haze writes (see README's layers)", sp.layer));
  }
  if (j.contains("require_finite")) {
    if (!j["require_finite"].is_boolean()) fail("require_finite", "expected true or false");
    sp.require_finite = j["require_finite"].get<bool>();
  }
  if (j.contains("save_images")) {
    if (!j["save_images"].is_string()) fail("save_images", "expected \"last\", \"all\" or \"none\"");
    sp.save_images = j["save_images"].get<std::string>();
    if (sp.save_images != "last" && sp.save_images != "all" && sp.save_images != "none")
      fail("save_images", fmt::format("\"{}\" is not one of last, all, none", sp.save_images));
  }
  if (j.contains("description") && !j["description"].is_string()) fail("description", "expected a string");

  json axes = json::array();
  for (const auto& a : sp.axes) axes.push_back({{"paths", a.paths}, {"values", a.values}});
  sp.canonical = {{"scene", fs::path(sp.scene).filename().string()},
                  {"set", sp.set},
                  {"axes", axes},
                  {"combine", sp.combine},
                  {"seeds", sp.seeds},
                  {"frames", sp.frames},
                  {"reference", sp.reference ? sp.reference->to_json() : json()},
                  {"layer", sp.layer},
                  {"require_finite", sp.require_finite},
                  {"save_images", sp.save_images},
                  {"description", j.value("description", "")}};
  return sp;
}

std::vector<Run> expand(const SweepSpec& spec) {
  std::vector<Pick> picks;
  const size_t A = spec.axes.size();
  if (A == 0) {
    picks.push_back({});
  } else if (spec.combine == "zip") {
    for (size_t v = 0; v < spec.axes[0].values.size(); ++v) {
      Pick p;
      for (size_t a = 0; a < A; ++a) p.push_back({a, v});
      picks.push_back(p);
    }
  } else if (spec.combine == "each") {
    for (size_t a = 0; a < A; ++a)
      for (size_t v = 0; v < spec.axes[a].values.size(); ++v) picks.push_back({{a, v}});
  } else {
    std::vector<size_t> at(A, 0);
    for (;;) {
      Pick p;
      for (size_t a = 0; a < A; ++a) p.push_back({a, at[a]});
      picks.push_back(p);
      size_t a = A;  // the last axis changes fastest
      while (a > 0 && ++at[a - 1] == spec.axes[a - 1].values.size()) at[--a] = 0;
      if (a == 0) break;
    }
  }
  std::vector<Run> runs;
  std::vector<std::optional<uint32_t>> seeds;
  if (spec.seeds.empty()) seeds.push_back(std::nullopt);
  for (uint32_t s : spec.seeds) seeds.push_back(s);
  for (const Pick& p : picks)
    for (const auto& seed : seeds) {
      Run r;
      r.index = runs.size();
      r.overrides = spec.set;
      for (auto [a, v] : p) {
        const Axis& ax = spec.axes[a];
        for (size_t k = 0; k < ax.paths.size(); ++k) {
          const json& val = ax.paths.size() > 1 ? ax.values[v][k] : ax.values[v];
          r.settings[ax.paths[k]] = val;
          r.overrides.push_back(assignment(ax.paths[k], val));
        }
      }
      if (seed) {
        r.settings["render.seed"] = *seed;
        r.overrides.push_back(assignment("render.seed", *seed));
      }
      if (!spec.frames.empty()) r.overrides.push_back("render.frames=" + spec.frames);
      r.id = hash_key(
          json{{"overrides", r.overrides}, {"scene", fs::path(spec.scene).filename().string()}}.dump());
      runs.push_back(std::move(r));
    }
  return runs;
}

void check_runs(const SweepSpec& spec, const std::vector<Run>& runs) {
  try {
    scene::load(spec.scene, spec.set);
  } catch (const std::exception& e) {
    throw render::Error(fmt::format("{}: set: {}", spec.file, from_sweep(e.what())));
  }
  // Each value on its own first, so that the message names the axis.
  for (size_t a = 0; a < spec.axes.size(); ++a)
    for (size_t v = 0; v < spec.axes[a].values.size(); ++v) {
      std::vector<std::string> o = spec.set;
      for (size_t k = 0; k < spec.axes[a].paths.size(); ++k)
        o.push_back(assignment(spec.axes[a].paths[k], spec.axes[a].paths.size() > 1
                                                          ? spec.axes[a].values[v][k]
                                                          : spec.axes[a].values[v]));
      try {
        scene::load(spec.scene, o);
      } catch (const std::exception& e) {
        throw render::Error(
            fmt::format("{}: axes[{}].values[{}]: {}", spec.file, a, v, from_sweep(e.what())));
      }
    }
  for (const Run& r : runs) {
    try {
      // The free-form specs that the scene reader leaves to the parts: checked here, before any run.
      render::check_part_specs(scene::load(spec.scene, r.overrides));
    } catch (const std::exception& e) {
      throw render::Error(
          fmt::format("{}: run {} {}: {}", spec.file, r.index, r.settings.dump(), from_sweep(e.what())));
    }
  }
}

Shard parse_shard(const std::string& text) {
  Shard s;
  char slash = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &s.index, &slash, &s.count, &extra) != 3 || slash != '/' ||
      s.count < 1 || s.index < 0 || s.index >= s.count)
    throw render::Error(fmt::format(
        "--shard {}: expected i/N with 0 <= i < N, e.g. 0/4 (Slurm: $SLURM_ARRAY_TASK_ID/N)", text));
  return s;
}

std::vector<Run> shard_runs(const std::vector<Run>& runs, Shard shard) {
  std::vector<Run> out;
  for (const Run& r : runs)
    if (r.index % size_t(shard.count) == size_t(shard.index)) out.push_back(r);
  return out;
}

std::string shard_dir(const std::string& out, Shard shard) {
  if (shard.count == 1) return out;
  return (fs::path(out) / fmt::format("shard-{}-of-{}", shard.index, shard.count)).string();
}

std::vector<json> read_results(const std::string& path) {
  std::vector<json> rows;
  std::ifstream in(path, std::ios::binary);
  if (!in) return rows;
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::string kept;
  size_t at = 0, line_no = 0;
  bool torn = false;
  while (at < text.size()) {
    size_t nl = text.find('\n', at);
    const bool last = nl == std::string::npos;
    std::string line = text.substr(at, last ? std::string::npos : nl - at);
    at = last ? text.size() : nl + 1;
    ++line_no;
    if (line.empty()) continue;
    json row = json::parse(line, nullptr, false);
    if (row.is_discarded() || !row.is_object() || !row.contains("run")) {
      if (!last && at < text.size())
        throw render::Error(fmt::format(
            "{}: line {} is not a result row; the file was edited by hand? Move it away", path, line_no));
      torn = true;  // the run in flight when the sweep was killed: it runs again
      continue;
    }
    if (last)
      torn = true;  // a row without its newline was cut short after its JSON: keep it, finish the line
    rows.push_back(row);
    kept += line + "\n";
  }
  if (torn) render::write_text(path, kept);
  return rows;
}

std::string results_csv(const std::vector<json>& rows) {
  std::vector<std::string> columns;
  std::set<std::string> seen;
  std::vector<std::map<std::string, std::string>> cells(rows.size());
  auto put = [&](size_t i, const std::string& c, const json& v) {
    if (v.is_null()) return;
    if (seen.insert(c).second) columns.push_back(c);
    cells[i][c] = v.is_string() ? v.get<std::string>() : v.dump();
  };
  for (size_t i = 0; i < rows.size(); ++i) {
    const json& r = rows[i];
    for (const char* k : {"run", "index", "frames", "samples"}) put(i, k, r.value(k, json()));
    for (const auto& [k, v] : r["settings"].items()) put(i, k, v);
    const json& t = r["time"];
    for (const auto& [k, v] : t.items()) put(i, k, v);
    put(i, "memory_mb", r["memory"]["total"].get<double>() / 1e6);
    put(i, "memory_peak_mb", r["memory"]["peak"].get<double>() / 1e6);
    if (r.contains("metrics"))
      for (const auto& [k, v] : r["metrics"].items()) put(i, k, v);
    if (r.contains("temporal"))
      for (const auto& [k, v] : r["temporal"].items()) put(i, "temporal_" + k, v);
    put(i, "nonfinite", r.value("nonfinite", json()));
    if (r.contains("discarded"))
      for (const auto& [k, v] : r["discarded"].items()) put(i, "discarded_" + k, v);
    for (const auto& [k, v] : r["passes"].items()) put(i, "pass_" + k + "_ms", v["ms_per_frame"]);
    for (const auto& [k, v] : r["memory"]["per_category"].items())
      put(i, "mem_" + k + "_mb", v.get<double>() / 1e6);
  }
  auto append = [](std::string& out, size_t c, const std::string& s) {
    if (c > 0) out += ',';
    if (s.find_first_of(",\"\n") == std::string::npos) {
      out += s;
      return;
    }
    out += '"';
    for (char ch : s) out += ch == '"' ? "\"\"" : std::string(1, ch);
    out += '"';
  };
  std::string out;
  for (size_t c = 0; c < columns.size(); ++c) append(out, c, columns[c]);
  out += '\n';
  for (const auto& row : cells) {
    for (size_t c = 0; c < columns.size(); ++c) {
      auto it = row.find(columns[c]);
      append(out, c, it == row.end() ? std::string() : it->second);
    }
    out += '\n';
  }
  return out;
}

json summary_of_row(const json& row) {
  const std::string frames = row.value("frames", "0:0");
  const size_t colon = frames.find(':');
  int count = 1;
  if (colon != std::string::npos) count = std::stoi(frames.substr(colon + 1)) - std::stoi(frames) + 1;
  json passes = json::object();
  const json all = row.value("passes", json::object());
  for (const auto& [name, p] : all.items()) passes[name] = p.value("ms_per_frame", 0.0);
  const json time = row.value("time", json::object());
  return {{"samples", row.value("samples", 0)},
          {"frames", count},
          {"render_s", time.value("render_s", 0.0)},
          {"gpu_ms_per_frame", time.value("gpu_ms_per_frame", 0.0)},
          {"passes", passes},
          {"memory", row.value("memory", json::object())}};
}

std::string stats_text(const std::string& dir) {
  const fs::path d(dir);
  if (fs::is_regular_file(d / "stats.json")) {
    std::ifstream f(d / "stats.json");
    json st = json::parse(f, nullptr, false);
    if (st.is_discarded() || !st.is_object())
      throw render::Error(fmt::format("{}: not a stats.json (bad JSON); render the folder again",
                                      (d / "stats.json").string()));
    return render::format_summary(render::summary_of_stats(st));
  }
  // A sweep folder, or one of its runs/<id> folders (the row of that run).
  std::string only;
  fs::path sweep = d;
  if (!fs::exists(d / "results.jsonl") && d.lexically_normal().parent_path().filename() == "runs") {
    only = d.lexically_normal().filename().string();
    sweep = d.lexically_normal().parent_path().parent_path();
  }
  if (!fs::exists(sweep / "results.jsonl"))
    throw render::Error(fmt::format(
        "{}: no stats.json or results.jsonl; pass a `haze render` --out folder, a sweep's --out or one of "
        "its runs/<id> folders",
        dir));
  std::string out;
  for (const json& row : read_results((sweep / "results.jsonl").string())) {
    if (!only.empty() && row["run"] != only) continue;
    out += fmt::format("run {} {}:\n", row.value("index", 0), row.value("settings", json::object()).dump());
    std::string s = render::format_summary(summary_of_row(row));
    for (size_t at = 0; at < s.size();) {  // indented under its run
      const size_t nl = s.find('\n', at);
      out += "  " + s.substr(at, nl - at + 1);
      at = nl + 1;
    }
  }
  if (out.empty())
    throw render::Error(fmt::format("{}: no finished run{} in {}", dir, only.empty() ? "" : " " + only,
                                    (sweep / "results.jsonl").string()));
  return out;
}

size_t count_nonfinite(const render::Image& img) {
  size_t n = 0;
  const size_t pixels = size_t(img.width) * img.height;
  for (const render::Layer& l : render::exr_layers()) {
    if (!l.present(img)) continue;
    for (size_t p = 0; p < pixels; ++p)
      for (size_t c = 0; c < l.channels.size(); ++c) n += !std::isfinite(l.value(img, p, int(c)));
  }
  return n;
}

namespace {

// Appends one line with a single write and syncs it: a kill leaves the row whole or (rarely) torn, and
// read_results drops a torn one.
void append_line(const std::string& path, const std::string& line) {
  int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  if (fd < 0) throw render::Error(fmt::format("cannot append to {}; check that --out is writable", path));
  std::string text = line + "\n";
  ssize_t n = ::write(fd, text.data(), text.size());
  ::fsync(fd);
  ::close(fd);
  if (n != ssize_t(text.size()))
    throw render::Error(fmt::format("cannot append to {}: short write; disk full?", path));
}

// The RGB layer's values of `img`, 3 floats per pixel (load_sweep admits RGB layers only).
std::vector<float> layer_values(const render::Image& img, const std::string& layer) {
  for (const render::Layer& l : render::exr_layers()) {
    if (l.name != layer) continue;
    if (!l.present(img))
      throw render::Error(fmt::format(
          "layer \"{}\" is not written for this scene (its pass is off); choose another layer", layer));
    const size_t pixels = size_t(img.width) * img.height;
    std::vector<float> v(pixels * 3);
    for (size_t p = 0; p < pixels; ++p)
      for (int c = 0; c < 3; ++c) v[p * 3 + size_t(c)] = l.value(img, p, c);
    return v;
  }
  throw render::Error(fmt::format("no layer \"{}\"", layer));
}

// Samples per frame: render.spp, or under render.time_budget_s the mean of what each frame reached.
json mean_samples(const render::RunSummary& rs) {
  int64_t sum = 0;
  for (const auto& f : rs.per_frame) sum += f["samples"].get<int64_t>();
  const int64_t n = int64_t(rs.per_frame.size());
  return sum % n == 0 ? json(sum / n) : json(double(sum) / double(n));
}

std::string relative_to(const std::string& path, const std::string& base) {
  return fs::relative(path, base).generic_string();
}

}  // namespace

int run_sweep(gpu::Context& ctx, const SweepSpec& spec, const std::string& out, Shard shard,
              const SweepHooks& hooks) {
  using clock = std::chrono::steady_clock;
  auto log = [&](const std::string& s) {
    if (hooks.log) hooks.log(s);
  };
  std::vector<Run> all = expand(spec);
  check_runs(spec, all);
  std::vector<Run> runs = shard_runs(all, shard);
  const std::string dir = shard_dir(out, shard);
  render::ensure_writable_dir(dir);
  // One sweep per folder: a different sweep file here would mix its rows with these.
  const std::string spec_path = (fs::path(dir) / "sweep.json").string();
  const std::string jsonl = (fs::path(dir) / "results.jsonl").string();
  const std::string csv = (fs::path(dir) / "results.csv").string();
  std::vector<json> rows = read_results(jsonl);
  // A folder without results belongs to no sweep yet (an earlier attempt may have failed before its first
  // row): its sweep.json is replaced.
  if (fs::exists(spec_path) && !rows.empty()) {
    std::ifstream f(spec_path);
    json old = json::parse(f, nullptr, false);
    if (old.is_discarded() || old != spec.canonical)
      throw render::Error(
          fmt::format("{} holds the results of a different sweep (its sweep.json differs from {}); "
                      "choose another --out, or delete it to start over",
                      dir, spec.file));
  } else {
    render::write_json(spec_path, spec.canonical);
  }
  std::set<std::string> done;
  for (const auto& r : rows) done.insert(r["run"].get<std::string>());
  std::vector<Run> todo;
  for (const Run& r : runs)
    if (!done.count(r.id)) todo.push_back(r);
  log(fmt::format(
      "sweep {}: {} runs{}, {} finished before, {} to do", spec.file, runs.size(),
      shard.count > 1 ? fmt::format(" in shard {}/{} of {}", shard.index, shard.count, all.size()) : "",
      runs.size() - todo.size(), todo.size()));
  if (hooks.progress) hooks.progress(0, todo.size(), nullptr, 0.0);

  std::unique_ptr<render::Renderer> r;
  int code = 0;
  double reference_s = 0;  // spent making references, kept out of the runs' ETA
  for (size_t i = 0; i < todo.size(); ++i) {
    const Run& run = todo[i];
    try {
      json reference_notes = json::array();
      auto t0 = clock::now();
      scene::Scene s = scene::load(spec.scene, run.overrides);
      const auto [first, last_frame] = scene::frame_range(s);
      const int last = last_frame;  // captured below: clang 14 lambdas cannot capture structured bindings
      std::string ref_dir;
      if (spec.reference) {
        ref_dir =
            (fs::path(out) / "references" / reference_key(reference_scene(s), *spec.reference)).string();
        ReferenceHooks rh;
        rh.on_frame = [&](const ReferenceFrame& f, bool cached) {
          if (cached) return;
          if (f.converged)
            log(fmt::format("reference frame {}: {} spp, error {:.3g} at quantile {} ({:.1f} s)", f.frame,
                            f.spp, f.error_quantile, spec.reference->quantile, f.seconds));
          else
            log("note: " + not_converged_note(f, *spec.reference));
        };
        const auto r0 = clock::now();
        const json info = make_reference(ctx, s, first, last, ref_dir, *spec.reference, rh, r);
        reference_s += std::chrono::duration<double>(clock::now() - r0).count();
        for (int f = first; f <= last; ++f)
          if (const json& fr = info["frames"][std::to_string(f)]; fr.contains("note"))
            reference_notes.push_back(fr["note"]);
      }
      const std::string run_dir = (fs::path(dir) / "runs" / run.id).string();
      if (spec.save_images != "none") render::ensure_writable_dir(run_dir);
      std::vector<std::vector<float>> test_frames;
      std::vector<LayerImage> ref_frames;
      json per_frame = json::array(), memory, images = json::array();
      size_t bad = 0;
      render::FrameLoop loop;
      loop.on_frame = [&](int f, const render::Image& img) {
        bad += count_nonfinite(img);
        json m = {{"frame", f}};
        if (spec.reference) {
          test_frames.push_back(layer_values(img, spec.layer));
          // The same layer on both sides (a reference holds every layer a sweep may name).
          ref_frames.push_back(read_layer(reference_frame_path(ref_dir, f), spec.layer));
          const size_t pixels = size_t(img.width) * img.height;
          Channels x{test_frames.back().data(), pixels, 3, 0, 3};
          m.update(image_metrics(x, ref_frames.back().view(), img.width, img.height));
        }
        per_frame.push_back(m);
        if (spec.save_images == "all" || (spec.save_images == "last" && f == last)) {
          std::string path = (fs::path(run_dir) / fmt::format("frame_{:04d}.exr", f)).string();
          render::write_exr(path, img);
          images.push_back(relative_to(path, dir));
        }
        if (f == last) memory = ctx.ledger().to_json();
      };
      const auto t_run = clock::now();  // the reference is made (or found) before this
      // Warm-up: one sample of the first frame, discarded, so that compilation at the first dispatch
      // (lavapipe compiles there) and pipeline creation stay out of the run's timings.
      scene::Scene warm = s;
      warm.render.spp = 1;
      warm.render.time_budget_s = 0;
      const double pipeline_ms = render::render_frames(ctx, warm, first, first, render::FrameLoop{}, r)
                                     .stats["pipeline_creation_ms"];
      ctx.ledger().reset_peak();
      render::RunSummary rs = render::render_frames(ctx, s, first, last, loop, r);
      const int frames = last - first + 1;
      json row = {{"run", run.id},
                  {"index", run.index},
                  {"settings", run.settings},
                  {"frames", fmt::format("{}:{}", first, last)},
                  {"samples", mean_samples(rs)},
                  {"nonfinite", bad},
                  {"discarded", rs.counters.discarded_json()},
                  {"device", ctx.device_name()}};
      row["time"] = {{"gpu_ms_per_frame", rs.gpu_ms / frames},
                     {"trace_ms_per_frame",
                      [&] {
                        double t = 0;
                        for (const auto& f : rs.per_frame) t += f["trace_gpu_ms"].get<double>();
                        return t / frames;
                      }()},
                     {"pipeline_ms", pipeline_ms},
                     {"setup_s", rs.setup_s},
                     {"render_s", rs.render_s},
                     {"wall_s", std::chrono::duration<double>(clock::now() - t0).count()},
                     {"reference_s", std::chrono::duration<double>(t_run - t0).count()}};
      json passes = json::object();
      for (const auto& [name, st] : rs.stats["passes"].items())
        passes[name] = {{"ms_per_frame", st["total_ms"].get<double>() / frames},
                        {"median_ms", st.value("median_ms", 0.0)},
                        {"count", st["count"]}};
      row["passes"] = passes;
      memory.erase("entries");  // per buffer: in stats of `haze render`; categories suffice here
      row["memory"] = memory;
      if (spec.reference) {
        json mean = json::object();
        for (const auto& f : per_frame)
          for (const auto& [k, v] : f.items())
            if (k != "frame" && v.is_number()) mean[k] = mean.value(k, 0.0) + v.get<double>() / frames;
        for (const auto& f : per_frame)  // PSNR of identical frames is "inf"
          if (f.contains("psnr") && f["psnr"].is_string()) mean["psnr"] = "inf";
        row["metrics"] = mean;
        if (frames > 1) {
          const size_t pixels = size_t(s.render.width) * s.render.height;
          std::vector<Channels> x, y;
          for (int f = 0; f < frames; ++f) {
            x.push_back({test_frames[size_t(f)].data(), pixels, 3, 0, 3});
            y.push_back(ref_frames[size_t(f)].view());
          }
          row["temporal"] = temporal(x, y).to_json();
        }
        row["reference"] = relative_to(ref_dir, dir);
        row["layers"] = compared_layers(spec.layer, spec.layer);
        row["reference_notes"] = reference_notes;  // frames of the reference that did not converge
        row["per_frame"] = per_frame;
      }
      row["images"] = images;
      row["preview"] = {{"exposure", s.render.exposure}, {"tonemap", s.render.tonemap}};  // for the report
      row["notes"] = rs.notes;
      append_line(jsonl, row.dump());
      rows.push_back(row);
      render::write_text(csv, results_csv(rows));
      if (bad > 0 && spec.require_finite) {
        log(fmt::format("run {} {}: {} NaN or Inf values", run.index, run.settings.dump(), bad));
        code = 4;
      }
      // A sample the estimator dropped (a non-finite radiance) or cut (step cap, majorant) is what a
      // finite image can hide: require_finite asks for none.
      if (rs.counters.discarded() > 0 && spec.require_finite) {
        log(fmt::format("run {} {}: samples discarded {}", run.index, run.settings.dump(),
                        rs.counters.discarded_json().dump()));
        code = 4;
      }
    } catch (const render::Error& e) {
      // A failure in a run names the sweep and the run; the rows written so far stay.
      throw render::Error(
          fmt::format("{}: run {} {}: {}", spec.file, run.index, run.settings.dump(), e.what()));
    } catch (const std::exception& e) {
      throw render::Error(
          fmt::format("{}: run {} {}: {}", spec.file, run.index, run.settings.dump(), e.what()));
    }
    if (hooks.progress) hooks.progress(i + 1, todo.size(), &rows.back(), reference_s);
  }
  if (todo.empty()) render::write_text(csv, results_csv(rows));
  return code;
}

json merge_sweep(const SweepSpec& spec, const std::string& out) {
  std::vector<Run> all = expand(spec);
  std::map<std::string, const Run*> by_id;
  for (const Run& r : all) by_id[r.id] = &r;
  std::vector<std::string> sources;
  if (fs::exists(fs::path(out) / "results.jsonl")) sources.push_back(out);
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(out, ec))
    if (e.is_directory() && e.path().filename().string().rfind("shard-", 0) == 0)
      sources.push_back(e.path().string());
  std::sort(sources.begin() + (sources.size() && sources[0] == out ? 1 : 0), sources.end());
  if (sources.empty())
    throw render::Error(
        fmt::format("{}: no results.jsonl and no shard-*/ folders to merge; run the shards first", out));
  std::map<size_t, json> merged;
  size_t duplicates = 0, foreign = 0;
  for (const auto& src : sources) {
    const std::string spec_path = (fs::path(src) / "sweep.json").string();
    std::ifstream f(spec_path);
    json s = json::parse(f, nullptr, false);
    if (s.is_discarded() || s != spec.canonical)
      throw render::Error(fmt::format(
          "{} holds the results of a different sweep than {}; move it away and merge again", src, spec.file));
    for (json row : read_results((fs::path(src) / "results.jsonl").string())) {
      auto it = by_id.find(row["run"].get<std::string>());
      if (it == by_id.end()) {
        ++foreign;
        continue;
      }
      if (merged.count(it->second->index)) {
        ++duplicates;
        continue;
      }
      // Paths in a row are relative to the folder holding its results.jsonl.
      json images = json::array();
      for (const auto& im : row["images"])
        images.push_back(relative_to((fs::path(src) / im.get<std::string>()).string(), out));
      row["images"] = images;
      if (row.contains("reference"))
        row["reference"] = relative_to((fs::path(src) / row["reference"].get<std::string>()).string(), out);
      merged[it->second->index] = row;
    }
  }
  std::vector<json> rows;
  std::string text;
  for (auto& [i, row] : merged) {
    text += row.dump() + "\n";
    rows.push_back(row);
  }
  render::write_json((fs::path(out) / "sweep.json").string(), spec.canonical);
  render::write_text((fs::path(out) / "results.jsonl").string(), text);
  render::write_text((fs::path(out) / "results.csv").string(), results_csv(rows));
  json summary = {{"runs", all.size()},
                  {"merged", rows.size()},
                  {"duplicates", duplicates},
                  {"foreign", foreign},
                  {"sources", sources.size()}};
  if (rows.size() < all.size()) {
    std::string first_missing;
    for (const Run& r : all)
      if (!merged.count(r.index)) {
        first_missing = fmt::format("run {} {}", r.index, r.settings.dump());
        break;
      }
    throw render::Error(
        fmt::format("{}: merged {} of {} runs; {} missing (first: {}); run the missing shards, then merge "
                    "again",
                    out, rows.size(), all.size(), all.size() - rows.size(), first_missing));
  }
  return summary;
}

}  // namespace haze::eval
