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

// "a.b.c=1, d=2" and a short form with each path's last part.
std::pair<std::string, std::string> labels(const json& settings) {
  std::string full, brief;
  for (const auto& [k, v] : settings.items()) {
    full += (full.empty() ? "" : ", ") + k + "=" + value_text(v);
    size_t dot = k.rfind('.');
    brief +=
        (brief.empty() ? "" : " ") + (dot == std::string::npos ? k : k.substr(dot + 1)) + "=" + value_text(v);
  }
  if (full.empty()) full = brief = "base scene";
  return {full, brief};
}

double number(const json& v) {
  if (v.is_number()) return v.get<double>();
  if (v.is_string() && v.get<std::string>() == "inf") return INFINITY;
  return NAN;
}

}  // namespace

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
    auto [full, brief] = labels(settings);
    json g = {{"settings", settings}, {"label", full}, {"short", brief}, {"runs", rs.size()}};
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
  return {{"dir", fs::absolute(d).string()},
          {"layers", layers},
          {"metric", o.metric},
          {"groups", out},
          {"runs", rows.size()},
          {"sweep", spec},
          {"device", rows.front().value("device", "")},
          {"colour_axis", axes.empty() ? json() : axes[0]["paths"][0]}};
}

namespace {

// Tonemapped preview (ACES fit, 0 EV) of an RGB plane set, as haze's PNG previews are made.
std::vector<uint32_t> preview(const std::vector<float>& rgb, size_t pixels) {
  std::vector<uint32_t> px(pixels);
  for (size_t p = 0; p < pixels; ++p)
    px[p] = glsl::pack_srgb8(glsl::tonemap_aces(glm::vec3(rgb[p * 3], rgb[p * 3 + 1], rgb[p * 3 + 2])));
  return px;
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
    render::write_png_rgb8(png, W, H, preview(x.data, pixels));
    json col = {{"label", (*g)["short"]}, {"png", png}};
    if (g->contains("reference_image")) {
      LayerImage r = read_layer((*g)["reference_image"].get<std::string>(), layer);
      if (ref_path.empty()) {
        ref_path = (fig / "reference.png").string();
        render::write_png_rgb8(ref_path, W, H, preview(r.data, pixels));
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
       "img.plot{max-width:100%;display:block;margin:1em 0}.bad{color:#b00}figure{margin:0}"
       "figcaption{font-size:12px;color:#555}</style></head><body>\n";
  const json& sw = data["sweep"];
  h += fmt::format(
      "<h1>haze sweep report</h1>\n<p>{} runs in {} settings on {}. Sweep of <code>{}</code>{}.</p>\n",
      data["runs"].get<size_t>(), data["groups"].size(), html_escape(data["device"].get<std::string>()),
      html_escape(sw.value("scene", "?")),
      sw.value("description", "").empty() ? "" : ": " + html_escape(sw.value("description", "")));
  if (sw.contains("reference") && sw["reference"].is_object())
    h += fmt::format(
        "<p>Errors against a reference rendered until {}% of the pixels have a relative standard "
        "error below {} (at most {} spp), compared as <code>{}</code>. Time is the GPU time "
        "of all passes per frame (timestamps), averaged over seeds.</p>\n",
        sw["reference"]["quantile"].get<double>() * 100, fmt_number(sw["reference"]["target"]),
        sw["reference"]["max_spp"].get<int>(), html_escape(layers_text(data["layers"])));
  auto figure = [&](const std::string& name, const std::string& caption) {
    if (std::find(made.begin(), made.end(), name) == made.end()) return;
    h += fmt::format(
        "<figure><img class=\"plot\" alt=\"{}\" src=\"data:image/png;base64,{}\">"
        "<figcaption>{}</figcaption></figure>\n",
        name, base64(read_file((fig / name).string())), caption);
  };
  figure("pareto.png",
         "Error against GPU time per frame, one point per setting (mean over seeds, bars: &plusmn;1 sd); the "
         "Pareto front (no setting is both faster and more accurate) is outlined and joined.");
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
    figure(
        "images.png",
        "Last frame of the first seed of the Pareto settings (fastest first), then the others by error: "
        "tonemapped (ACES, 0 EV), the crop where the error is largest (yellow box), and the per-pixel relMSE "
        "(log scale).");
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
