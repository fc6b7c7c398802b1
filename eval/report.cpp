#include "eval/report.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

#include "eval/compare.hpp"
#include "eval/metrics.hpp"
#include "eval/reference.hpp"
#include "eval/sweep.hpp"
#include "render/output.hpp"
#include "shaders/glsl.hpp"

namespace haze::eval {

extern const char* const kReportPy;  // eval/report.py, embedded by CMake

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::string html_escape(const std::string& s) {
  std::string o;
  for (char c : s) {
    if (c == '<')
      o += "&lt;";
    else if (c == '>')
      o += "&gt;";
    else if (c == '&')
      o += "&amp;";
    else if (c == '"')
      o += "&quot;";
    else
      o += c;
  }
  return o;
}

std::string base64(const std::string& bytes) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string o;
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    uint32_t v = uint8_t(bytes[i]) << 16 | uint8_t(bytes[i + 1]) << 8 | uint8_t(bytes[i + 2]);
    for (int s = 18; s >= 0; s -= 6) o += k[(v >> s) & 63];
  }
  if (i < bytes.size()) {
    uint32_t v = uint8_t(bytes[i]) << 16 | (i + 1 < bytes.size() ? uint8_t(bytes[i + 1]) << 8 : 0);
    o += k[(v >> 18) & 63];
    o += k[(v >> 12) & 63];
    o += i + 1 < bytes.size() ? k[(v >> 6) & 63] : '=';
    o += '=';
  }
  return o;
}

std::string read_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
}

std::string value_text(const json& v) {
  return v.is_string() ? v.get<std::string>() : v.dump();
}

// A key the setting does not use: a.b.c while a.b.enabled is false (guiding off has no probability).
bool unused(const json& settings, const std::string& key) {
  const size_t dot = key.rfind('.');
  if (dot == std::string::npos || key.substr(dot + 1) == "enabled") return false;
  const std::string switch_key = key.substr(0, dot) + ".enabled";
  return settings.contains(switch_key) && settings[switch_key] == false;
}

}  // namespace

std::pair<std::string, std::string> setting_labels(const json& settings) {
  std::string full, brief;
  for (const auto& [k, v] : settings.items()) {
    if (unused(settings, k)) continue;
    full += (full.empty() ? "" : ", ") + k + "=" + value_text(v);
    size_t dot = k.rfind('.');
    brief +=
        (brief.empty() ? "" : " ") + (dot == std::string::npos ? k : k.substr(dot + 1)) + "=" + value_text(v);
  }
  if (full.empty()) full = brief = "base scene";
  return {full, brief};
}

namespace {

double number(const json& v) {
  if (v.is_number()) return v.get<double>();
  if (v.is_string() && v.get<std::string>() == "inf") return INFINITY;
  return NAN;
}

}  // namespace

namespace {

// log-log linear interpolation of (time, error) points at t; NaN outside their time range.
double interpolate(std::vector<std::pair<double, double>> pts, double t) {
  std::erase_if(pts,
                [](const auto& p) { return !(p.first > 0 && p.second > 0) || !std::isfinite(p.second); });
  std::sort(pts.begin(), pts.end());
  if (pts.empty() || t < pts.front().first * (1 - 1e-9) || t > pts.back().first * (1 + 1e-9)) return NAN;
  if (pts.size() == 1) return pts[0].second;
  for (size_t i = 1; i < pts.size(); ++i) {
    if (t > pts[i].first && i + 1 < pts.size()) continue;
    const auto [t0, e0] = pts[i - 1];
    const auto [t1, e1] = pts[i];
    const double w = t1 > t0 ? std::clamp(std::log(t / t0) / std::log(t1 / t0), 0.0, 1.0) : 0.0;
    return std::exp(std::log(e0) + w * (std::log(e1) - std::log(e0)));
  }
  return NAN;
}

}  // namespace

namespace {

// The axis that buys accuracy with time: render.spp or render.time_budget_s ("" when neither varies).
std::string cost_axis(const std::vector<json>& rows) {
  for (const char* c : {"render.spp", "render.time_budget_s"})
    for (const auto& r : rows)
      if (r["settings"].contains(c)) return c;
  return "";
}

}  // namespace

json equal_time_table(const std::vector<json>& rows, const std::string& metric) {
  const std::string cost = cost_axis(rows);
  if (cost.empty()) return nullptr;
  struct Curve {
    json settings;
    std::map<std::string, std::vector<std::pair<double, double>>> by_seed;  // seed -> (time, error)
    std::map<std::string, std::pair<double, double>> by_cost;               // cost -> summed (time, error)
    std::map<std::string, int> count;                                       // cost -> rows
  };
  std::vector<std::string> order;
  std::map<std::string, Curve> curves;
  for (const auto& r : rows) {
    if (!r.contains("metrics") || !r["metrics"].contains(metric)) continue;
    json s = r["settings"];
    const std::string seed = s.value("render.seed", json()).dump(), c = s.value(cost, json()).dump();
    s.erase("render.seed");
    s.erase(cost);
    const std::string key = s.dump();
    if (!curves.count(key)) order.push_back(key);
    Curve& cv = curves[key];
    cv.settings = s;
    const double t = r["time"]["gpu_ms_per_frame"].get<double>(), e = number(r["metrics"][metric]);
    cv.by_seed[seed].emplace_back(t, e);
    cv.by_cost[c].first += t;
    cv.by_cost[c].second += e;
    cv.count[c] += 1;
  }
  if (curves.size() < 2) return nullptr;
  auto mean_curve = [](const Curve& cv) {
    std::vector<std::pair<double, double>> pts;
    for (const auto& [c, sum] : cv.by_cost)
      pts.emplace_back(sum.first / cv.count.at(c), sum.second / cv.count.at(c));
    return pts;
  };
  // The budgets lie where every curve, and every seed's own curve, has points on both sides.
  double lo = 0, hi = INFINITY;
  json labels = json::array();
  for (const auto& key : order) {
    auto cover = [&](const std::vector<std::pair<double, double>>& pts) {
      double a = INFINITY, b = 0;
      for (const auto& p : pts) a = std::min(a, p.first), b = std::max(b, p.first);
      lo = std::max(lo, a);
      hi = std::min(hi, b);
    };
    cover(mean_curve(curves[key]));
    for (const auto& [seed, pts] : curves[key].by_seed) cover(pts);
    labels.push_back(setting_labels(curves[key].settings).first);
  }
  json out = {{"cost_axis", cost}, {"metric", metric}, {"curves", labels}, {"budgets", json::array()}};
  if (!(lo <= hi)) {
    out["note"] = fmt::format(
        "the settings' GPU times do not overlap (the slowest setting's cheapest run takes {:.3g} ms per "
        "frame, the fastest setting's dearest {:.3g}); widen the {} axis so that they do",
        lo, hi, cost);
    return out;
  }
  std::vector<double> budgets = {lo};
  if (hi > lo * 1.01) budgets = {lo, std::sqrt(lo * hi), hi};
  for (double b : budgets) {
    std::vector<double> err;
    for (const auto& key : order) err.push_back(interpolate(mean_curve(curves[key]), b));
    size_t w = 0;
    for (size_t i = 1; i < err.size(); ++i)
      if (err[i] < err[w]) w = i;
    const Curve& win = curves[order[w]];
    json rows_out = json::array();
    for (size_t i = 0; i < order.size(); ++i) {
      const Curve& cv = curves[order[i]];
      std::vector<double> ratios;
      for (const auto& [seed, pts] : cv.by_seed) {
        auto it = win.by_seed.find(seed);
        if (it == win.by_seed.end()) continue;
        const double r = interpolate(pts, b) / interpolate(it->second, b);
        if (std::isfinite(r)) ratios.push_back(r);
      }
      double mean = 0, sd = 0;
      for (double r : ratios) mean += r / double(ratios.size());
      for (double r : ratios) sd += (r - mean) * (r - mean);
      sd = ratios.size() > 1 ? std::sqrt(sd / double(ratios.size() - 1)) : 0.0;
      auto [full, brief] = setting_labels(cv.settings);
      rows_out.push_back({{"label", full},
                          {"short", brief},
                          {"error", err[i]},
                          {"ratio", err[i] / err[w]},
                          {"ratio_mean", ratios.empty() ? json() : json(mean)},
                          {"ratio_sd", ratios.empty() ? json() : json(sd)},
                          {"seeds", ratios.size()}});
    }
    out["budgets"].push_back({{"ms", b}, {"winner", setting_labels(win.settings).first}, {"rows", rows_out}});
  }
  return out;
}

json report_data(const std::string& dir, const ReportOptions& o) {
  const fs::path d(dir);
  if (!fs::exists(d / "results.jsonl")) {
    bool shards = false;
    std::error_code ec;
    for (const auto& e : fs::directory_iterator(d, ec))
      shards |= e.path().filename().string().rfind("shard-", 0) == 0;
    throw render::Error(
        shards ? fmt::format("{}: only shard results; join them with `haze sweep SWEEP.json --out {} "
                             "--merge` first",
                             dir, dir)
               : fmt::format("{}: no results.jsonl; run `haze sweep SWEEP.json --out {}` first", dir, dir));
  }
  static const std::set<std::string> metrics = {"relmse", "smape", "mse", "flip_ldr", "flip_hdr"};
  if (!metrics.count(o.metric))
    throw render::Error(
        fmt::format("--metric {}: not one of relmse, smape, mse, flip_ldr, flip_hdr", o.metric));
  std::vector<json> rows = read_results((d / "results.jsonl").string());
  if (rows.empty())
    throw render::Error(fmt::format("{}: results.jsonl has no runs yet; let the sweep finish a run", dir));
  json spec = json::object();
  if (std::ifstream f(d / "sweep.json"); f) spec = json::parse(f, nullptr, false);
  if (spec.is_discarded()) spec = json::object();

  const std::string cost = cost_axis(rows);
  // Group by the settings without the seed, in the sweep's order.
  std::vector<std::string> order;
  std::map<std::string, std::vector<const json*>> groups;
  for (const auto& r : rows) {
    json s = r["settings"];
    s.erase("render.seed");
    std::string key = s.dump();
    if (!groups.count(key)) order.push_back(key);
    groups[key].push_back(&r);
  }
  json out = json::array();
  for (const auto& key : order) {
    const auto& rs = groups[key];
    json settings = json::parse(key);
    auto [full, brief] = setting_labels(settings);
    json g = {{"settings", settings}, {"label", full}, {"short", brief}, {"runs", rs.size()}};
    // Its curve: the setting without the cost axis (one colour and marker per curve in the plots).
    json curve = settings;
    if (!cost.empty()) curve.erase(cost);
    g["curve"] = setting_labels(curve).second;
    g["preview"] = rs.front()->value("preview", json{{"exposure", 0.0}, {"tonemap", "aces"}});
    double time = 0;
    std::vector<double> errors;
    json passes = json::object(), memory = json::object(), metric_means = json::object();
    size_t bad = 0;
    for (const json* r : rs) {
      time += (*r)["time"]["gpu_ms_per_frame"].get<double>() / double(rs.size());
      for (const auto& [p, v] : (*r)["passes"].items())
        passes[p] = passes.value(p, 0.0) + v["ms_per_frame"].get<double>() / double(rs.size());
      for (const auto& [c, v] : (*r)["memory"]["per_category"].items())
        memory[c] = memory.value(c, 0.0) + v.get<double>() / 1e6 / double(rs.size());
      if (r->contains("metrics")) {
        for (const auto& [m, v] : (*r)["metrics"].items())
          metric_means[m] = metric_means.value(m, 0.0) + number(v) / double(rs.size());
        if ((*r)["metrics"].contains(o.metric)) errors.push_back(number((*r)["metrics"][o.metric]));
      }
      bad += (*r).value("nonfinite", size_t(0));
    }
    g["time"] = time;
    g["passes"] = passes;
    g["memory"] = memory;
    g["memory_mb"] = [&] {
      double t = 0;
      for (const json* r : rs) t += (*r)["memory"]["total"].get<double>() / 1e6 / double(rs.size());
      return t;
    }();
    g["metrics"] = metric_means;
    g["nonfinite"] = bad;
    if (!errors.empty() && errors.size() == rs.size()) {
      double mean = 0, sd = 0;
      for (double e : errors) mean += e / double(errors.size());
      for (double e : errors) sd += (e - mean) * (e - mean);
      sd = errors.size() > 1 ? std::sqrt(sd / double(errors.size() - 1)) : 0.0;
      g["error"] = mean;
      g["error_sd"] = sd;
    }
    // The image grid shows a group's first run that kept an image, and the reference frame it was compared
    // with.
    for (const json* r : rs) {
      if (!r->contains("images") || (*r)["images"].empty()) continue;
      g["image"] = (d / (*r)["images"].back().get<std::string>()).string();
      if (r->contains("reference")) {
        const std::string frames = (*r)["frames"].get<std::string>();
        const int last = std::stoi(frames.substr(frames.find(':') + 1));
        g["reference_image"] =
            reference_frame_path((d / (*r)["reference"].get<std::string>()).string(), last);
      }
      break;
    }
    out.push_back(g);
  }
  // Pareto front of (time, error): no other group is at least as fast and as accurate, and better in one.
  for (auto& g : out) {
    bool front = g.contains("error") && std::isfinite(g["error"].get<double>());
    for (const auto& h : out) {
      if (!front || &h == &g || !h.contains("error")) continue;
      const double tg = g["time"], eg = g["error"], th = h["time"], eh = h["error"];
      if (th <= tg && eh <= eg && (th < tg || eh < eg)) front = false;
    }
    g["pareto"] = front;
  }
  json axes = spec.value("axes", json::array());
  // The layers the rows compared (rows before results named them compared the sweep's layer with R, G, B).
  json layers = rows.front().value("layers", compared_layers(spec.value("layer", ""), ""));
  for (const auto& r : rows)
    if (r.value("layers", layers) != layers)
      throw render::Error(fmt::format("{}: rows compared different layers ({} and {}); one sweep, one layer",
                                      dir, layers_text(layers), layers_text(r["layers"])));
  json notes = json::array();  // of references that did not converge, each once
  for (const auto& r : rows)
    for (const auto& n : r.value("reference_notes", json::array()))
      if (std::find(notes.begin(), notes.end(), n) == notes.end()) notes.push_back(n);
  return {{"dir", fs::absolute(d).string()},
          {"layers", layers},
          {"equal_time", equal_time_table(rows, o.metric)},
          {"reference_notes", notes},
          {"cost_axis", cost},
          {"metric", o.metric},
          {"groups", out},
          {"runs", rows.size()},
          {"sweep", spec},
          {"device", rows.front().value("device", "")},
          {"axes", axes}};
}

namespace {

// The preview of an RGB plane set at the exposure and tone curve of the scene the group rendered.
std::vector<uint32_t> preview(const std::vector<float>& rgb, const json& g) {
  const json p = g.value("preview", json::object());
  return render::preview_srgb8(rgb, p.value("exposure", 0.f), p.value("tonemap", "aces"));
}

// The image grid's inputs: previews and per-pixel relMSE maps of the chosen groups' first runs, and the
// crop window where their error concentrates.
json prepare_images(const json& data, const fs::path& fig, const ReportOptions& o) {
  // Pareto groups by time first, then the rest by error: the most informative columns.
  std::vector<const json*> pick;
  for (const auto& g : data["groups"])
    if (g["pareto"].get<bool>()) pick.push_back(&g);
  std::sort(pick.begin(), pick.end(), [](auto a, auto b) { return (*a)["time"] < (*b)["time"]; });
  std::vector<const json*> rest;
  for (const auto& g : data["groups"])
    if (!g["pareto"].get<bool>()) rest.push_back(&g);
  std::stable_sort(rest.begin(), rest.end(),
                   [](auto a, auto b) { return a->value("error", INFINITY) < b->value("error", INFINITY); });
  pick.insert(pick.end(), rest.begin(), rest.end());
  const std::string layer = data["sweep"].value("layer", "");
  json cols = json::array();
  int W = 0, H = 0;
  std::vector<std::vector<float>> errs;
  std::string ref_path;
  for (const json* g : pick) {
    if (int(cols.size()) >= o.max_images) break;
    if (!g->contains("image")) continue;
    LayerImage x = read_layer((*g)["image"].get<std::string>(), layer, false);
    if (W == 0) {
      W = x.width;
      H = x.height;
    }
    if (x.width != W || x.height != H) continue;  // one grid, one size
    const size_t pixels = size_t(W) * H;
    const int k = int(cols.size());
    const std::string png = (fig / fmt::format("column_{}.png", k)).string();
    render::write_png_rgb8(png, W, H, preview(x.data, *g));
    json col = {{"label", (*g)["short"]}, {"png", png}};
    if (g->contains("reference_image")) {
      LayerImage r = read_layer((*g)["reference_image"].get<std::string>(), layer);
      if (ref_path.empty()) {
        ref_path = (fig / "reference.png").string();
        render::write_png_rgb8(ref_path, W, H, preview(r.data, *g));
      }
      // Per-pixel relMSE, the mean over R, G, B.
      std::vector<float> e(pixels);
      double mean = 0;
      for (size_t p = 0; p < pixels; ++p) {
        double s = 0;
        for (size_t c = 0; c < 3; ++c) s += relmse_term(x.data[p * 3 + c], r.data[p * 3 + c]) / 3;
        e[p] = std::isfinite(s) ? float(s) : 0.f;
        mean += e[p] / double(pixels);
      }
      const std::string ep = (fig / fmt::format("column_{}.f32", k)).string();
      render::write_text(ep, std::string(reinterpret_cast<const char*>(e.data()), e.size() * 4));
      col["error"] = ep;
      col["mean_error"] = mean;
      errs.push_back(std::move(e));
    }
    cols.push_back(col);
  }
  if (cols.empty()) return json();
  if (!ref_path.empty()) cols.insert(cols.begin(), json{{"label", "reference"}, {"png", ref_path}});
  // The crop: the quarter-size window with the largest summed error over the columns (integral image).
  const int cw = std::min(W, std::max(8, W / 4)), ch = std::min(H, std::max(8, H / 4));
  std::vector<double> I(size_t(W + 1) * (H + 1), 0.0);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      double v = 0;
      for (const auto& e : errs) v += e[size_t(y) * W + x];
      I[size_t(y + 1) * (W + 1) + x + 1] =
          v + I[size_t(y) * (W + 1) + x + 1] + I[size_t(y + 1) * (W + 1) + x] - I[size_t(y) * (W + 1) + x];
    }
  int bx = 0, by = 0;
  double best = -1;
  for (int y = 0; y + ch <= H; ++y)
    for (int x = 0; x + cw <= W; ++x) {
      auto at = [&](int xx, int yy) { return I[size_t(yy) * (W + 1) + xx]; };
      double s = at(x + cw, y + ch) - at(x, y + ch) - at(x + cw, y) + at(x, y);
      if (s > best) best = s, bx = x, by = y;
    }
  return {{"columns", cols}, {"width", W}, {"height", H}, {"crop", {bx, by, cw, ch}}};
}

std::string fmt_number(const json& v) {
  if (!v.is_number()) return v.is_string() ? html_escape(v.get<std::string>()) : "";
  double x = v.get<double>();
  return std::isfinite(x) ? fmt::format("{:.4g}", x) : (x > 0 ? "inf" : "nan");
}

}  // namespace

std::vector<std::string> report_summary(const json& data) {
  std::vector<std::string> out;
  const json& sw = data["sweep"];
  const bool metrics = sw.contains("reference") && sw["reference"].is_object();
  out.push_back(fmt::format("{} runs of {} settings on {}{}.", data["runs"].get<size_t>(),
                            data["groups"].size(), data["device"].get<std::string>(),
                            metrics
                                ? fmt::format(", {} against a converged reference ({})",
                                              data["metric"].get<std::string>(), layers_text(data["layers"]))
                                : ", without a reference (no error metrics)"));
  if (metrics && data["layers"]["test"] != data["layers"]["reference"])
    out.push_back(
        fmt::format("Caution: these rows compared {}, two different images (rows written before "
                    "haze compared a layer with the same layer); run the sweep again into a new "
                    "folder.",
                    layers_text(data["layers"])));
  const json& notes = data["reference_notes"];
  if (!notes.empty())
    out.push_back(
        fmt::format("Caution: {} reference frame{} did not converge, so errors below the "
                    "reference's own are not resolved; the first: {}.",
                    notes.size(), notes.size() == 1 ? "" : "s", notes[0].get<std::string>()));
  const json& et = data["equal_time"];
  if (et.is_object()) {
    if (et.contains("note")) out.push_back("No equal-time answer: " + et["note"].get<std::string>() + ".");
    for (const auto& b : et["budgets"]) {
      std::string others;
      for (const auto& r : b["rows"]) {
        if (r["label"] == b["winner"]) continue;
        others += fmt::format("{}{} {:.2f}x", others.empty() ? "" : "; ", r["short"].get<std::string>(),
                              r["ratio"].get<double>());
        if (!r["ratio_mean"].is_null() && r["seeds"].get<size_t>() > 1)
          others += fmt::format(" (per seed {:.2f} ± {:.2f}, {} seeds)", r["ratio_mean"].get<double>(),
                                r["ratio_sd"].get<double>(), r["seeds"].get<size_t>());
      }
      double best = 0;
      for (const auto& r : b["rows"])
        if (r["label"] == b["winner"]) best = r["error"].get<double>();
      out.push_back(
          fmt::format("At equal time, {:.3g} ms per frame: {} wins with {} {:.3g}; the others' {} "
                      "is higher by: {}.",
                      b["ms"].get<double>(), b["winner"].get<std::string>(), et["metric"].get<std::string>(),
                      best, et["metric"].get<std::string>(), others));
    }
  }
  std::vector<std::string> front;
  for (const auto& g : data["groups"])
    if (g["pareto"].get<bool>()) front.push_back(g["short"].get<std::string>());
  if (!front.empty()) {
    std::string list;
    for (const auto& f : front) list += (list.empty() ? "" : "; ") + f;
    out.push_back(fmt::format("On the Pareto front of time and error: {}.", list));
  }
  size_t bad = 0;
  for (const auto& g : data["groups"]) bad += g["nonfinite"].get<size_t>() > 0;
  if (bad) out.push_back(fmt::format("{} settings produced NaN or Inf values (see the table).", bad));
  return out;
}

std::string write_report(const std::string& dir, const ReportOptions& o) {
  json data = report_data(dir, o);
  const std::string html_path = o.out.empty() ? (fs::path(dir) / "report.html").string() : o.out;
  const fs::path fig = fs::path(html_path).parent_path() / (fs::path(html_path).stem().string() + "_figures");
  render::ensure_writable_dir(fig.string());
  data["figures_dir"] = fig.string();
  data["metric_map"] = "relMSE per pixel";
  json images = prepare_images(data, fig, o);
  if (!images.is_null()) data["images"] = images;
  const std::string data_path = (fig / "data.json").string();
  render::write_json(data_path, data);

  // matplotlib draws; the script comes from the binary so that the report needs no source tree.
  // Debian's python3 (with Debian's matplotlib), not whichever python3 comes first on PATH; $HAZE_PYTHON
  // overrides.
  const char* env = std::getenv("HAZE_PYTHON");
  const std::string python = env && *env ? env : "/usr/bin/python3";
  const std::string cmd = fmt::format("'{}' - '{}' > '{}'", python, data_path, (fig / "made.json").string());
  FILE* py = ::popen(cmd.c_str(), "w");
  if (!py) throw render::Error("cannot start python3 for the report's plots; run scripts/setup.sh");
  std::fputs(kReportPy, py);
  if (::pclose(py) != 0)
    throw render::Error(
        "the report's plotting script failed (python3 with matplotlib and numpy; run scripts/setup.sh), "
        "see its message above");
  json made = json::parse(read_file((fig / "made.json").string()), nullptr, false);
  if (made.is_discarded()) throw render::Error("the report's plotting script printed no figure list");

  std::string h;
  h += "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n";
  h += "<script>window.hazeErrors=0;window.addEventListener('error',function(){"
       "document.documentElement.setAttribute('data-script-errors',++window.hazeErrors);});</script>\n";
  h += "<title>haze sweep report</title>\n<style>body{font-family:sans-serif;margin:2em;max-width:1200px}"
       "table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ccc;padding:3px "
       "6px;text-align:right}"
       "th{cursor:pointer;background:#f3f3f3}td.l{text-align:left}tr.front{background:#fff3e0}"
       "img.plot{max-width:100%;display:block;margin:1em "
       "0}img.wide{max-width:none}div.scroll{overflow-x:auto}.bad{color:#b00}figure{margin:0}"
       "figcaption{font-size:12px;color:#555}</style></head><body>\n";
  const json& sw = data["sweep"];
  h += "<h1>haze sweep report</h1>\n<h2>Summary</h2>\n<ul id=\"summary\">\n";
  for (const auto& line : report_summary(data)) h += "<li>" + html_escape(line) + "</li>\n";
  h += "</ul>\n<h2>The sweep</h2>\n";
  h +=
      fmt::format("<p>{} runs in {} settings on {}. Sweep of <code>{}</code>{}.</p>\n",
                  data["runs"].get<size_t>(), data["groups"].size(),
                  html_escape(data["device"].get<std::string>()), html_escape(sw.value("scene", "?")),
                  sw.value("description", "").empty() ? "" : ": " + html_escape(sw.value("description", "")));
  if (sw.contains("reference") && sw["reference"].is_object())
    h += fmt::format(
        "<p>Errors against a reference rendered until {}% of the pixels have a relative standard "
        "error below {} (at most {} spp), compared as <code>{}</code>. Time is the GPU time "
        "of all passes per frame (timestamps), averaged over seeds.</p>\n",
        sw["reference"]["quantile"].get<double>() * 100, fmt_number(sw["reference"]["target"]),
        sw["reference"]["max_spp"].get<int>(), html_escape(layers_text(data["layers"])));
  if (data["equal_time"].is_object() && !data["equal_time"]["budgets"].empty()) {
    const json& et = data["equal_time"];
    h += fmt::format(
        "<h2>Equal time</h2>\n<p>Each setting's {} against GPU time per frame, interpolated along "
        "<code>{}</code> in log-log (never extrapolated), at budgets inside the range every setting covers. "
        "Ratio: the setting's error over the winner's on the seed-mean curves; per seed: the same ratio on "
        "each seed's own curve, mean &plusmn; sd over the seeds.</p>\n<table id=\"equal-time\"><thead><tr>"
        "<th>GPU ms/frame</th><th>setting</th><th>{}</th><th>ratio to the winner</th><th>per seed</th>"
        "</tr></thead><tbody>\n",
        html_escape(et["metric"].get<std::string>()), html_escape(et["cost_axis"].get<std::string>()),
        html_escape(et["metric"].get<std::string>()));
    for (const auto& b : et["budgets"])
      for (const auto& r : b["rows"]) {
        const bool win = r["label"] == b["winner"];
        h += fmt::format("<tr{}><td>{}</td><td class=\"l\">{}{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\n",
                         win ? " class=\"front\"" : "", fmt_number(b["ms"]),
                         html_escape(r["label"].get<std::string>()), win ? " &#9733;" : "",
                         fmt_number(r["error"]), fmt_number(r["ratio"]),
                         r["ratio_mean"].is_null() || win
                             ? std::string("")
                             : fmt::format("{} &plusmn; {} ({} seeds)", fmt_number(r["ratio_mean"]),
                                           fmt_number(r["ratio_sd"]), r["seeds"].get<size_t>()));
      }
    h += "</tbody></table>\n";
  }
  // wide: shown at its own size (scrolling sideways), so that image panels stay large enough to judge.
  auto figure = [&](const std::string& name, const std::string& caption, bool wide = false) {
    if (std::find(made.begin(), made.end(), name) == made.end()) return;
    h += fmt::format(
        "<figure>{}<img class=\"plot{}\" alt=\"{}\" src=\"data:image/png;base64,{}\">{}"
        "<figcaption>{}</figcaption></figure>\n",
        wide ? "<div class=\"scroll\">" : "", wide ? " wide" : "", name,
        base64(read_file((fig / name).string())), wide ? "</div>" : "", caption);
  };
  figure("pareto.png",
         "Error against GPU time per frame, one point per setting (mean over seeds, bars: &plusmn;1 sd), one "
         "colour and marker per setting of every axis but the cost axis, whose points are joined; the Pareto "
         "front (no setting is both faster and more accurate) is outlined and drawn as a red step line; "
         "dotted verticals: the equal-time budgets.");
  // The table: every setting, sortable by a click on its header.
  h +=
      "<h2>Settings</h2>\n<table id=\"groups\"><thead><tr><th>setting</th><th>runs</th><th>GPU ms/frame</th>";
  const std::vector<std::string> ms = {"relmse", "smape", "mse", "psnr", "flip_ldr", "flip_hdr"};
  for (const auto& m : ms) h += "<th>" + m + "</th>";
  h += "<th>sd of " + o.metric +
       "</th><th>memory MB</th><th>NaN/Inf</th><th>Pareto</th></tr></thead><tbody>\n";
  for (const auto& g : data["groups"]) {
    h += fmt::format("<tr{}><td class=\"l\">{}</td><td>{}</td><td>{}</td>",
                     g["pareto"].get<bool>() ? " class=\"front\"" : "",
                     html_escape(g["label"].get<std::string>()), g["runs"].get<size_t>(),
                     fmt_number(g["time"]));
    for (const auto& m : ms) h += "<td>" + fmt_number(g["metrics"].value(m, json())) + "</td>";
    h += fmt::format("<td>{}</td><td>{}</td><td{}>{}</td><td>{}</td></tr>\n",
                     fmt_number(g.value("error_sd", json())), fmt_number(g["memory_mb"]),
                     g["nonfinite"].get<size_t>() ? " class=\"bad\"" : "", g["nonfinite"].get<size_t>(),
                     g["pareto"].get<bool>() ? "&#9733;" : "");
  }
  h += "</tbody></table>\n";
  h += "<h2>Time per pass</h2>\n";
  figure("passes.png", "GPU time per frame of each pass (timestamps), mean over seeds.");
  h += "<h2>Memory</h2>\n";
  figure("memory.png", "Device memory by ledger category, live at the last frame, mean over seeds.");
  if (data.contains("images")) {
    h += "<h2>Images</h2>\n";
    figure("images.png",
           "Last frame of the first seed of the Pareto settings (fastest first), then the others by error: "
           "tonemapped at the scene's exposure and tone curve, the crop where the error is largest (yellow "
           "box), "
           "and the per-pixel relMSE (log scale, one colour scale for the row).",
           true);
  }
  h +=
      "<script>\n"
      "window.addEventListener('load',function(){var im=document.querySelectorAll('img.plot'),ok=0;"
      "im.forEach(function(i){if(i.complete&&i.naturalWidth>0)ok++;});"
      "document.body.setAttribute('data-plots-loaded',ok+'/'+im.length);});\n"
      "document.querySelectorAll('#groups th').forEach(function(th,c){th.addEventListener('click',function(){"
      "var tb=document.querySelector('#groups tbody'),rs=Array.from(tb.rows),asc=th.dataset.asc!=='1';"
      "th.dataset.asc=asc?'1':'0';rs.sort(function(a,b){var "
      "x=a.cells[c].textContent,y=b.cells[c].textContent,"
      "nx=parseFloat(x),ny=parseFloat(y);var r=isNaN(nx)||isNaN(ny)?x.localeCompare(y):nx-ny;return "
      "asc?r:-r;});"
      "rs.forEach(function(r){tb.appendChild(r);});});});\n"
      "</script>\n</body></html>\n";
  render::write_text(html_path, h);
  return html_path;
}

}  // namespace haze::eval
