#include "eval/compare.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "eval/flip.hpp"
#include "eval/metrics.hpp"
#include "render/output.hpp"

namespace haze::eval {

namespace fs = std::filesystem;

namespace {

// One layer of an EXR as interleaved floats (channels in the reference's order).
// The layer's channels in the order haze writes them (R, G, B; X, Y, Z), not the file's alphabetical one:
// FLIP reads the first three as R, G, B.
std::vector<std::string> layer_channels(const render::ExrImage& img, const std::string& layer) {
  std::vector<std::string> out;
  for (const auto& c : img.channels) {
    bool base = c.find('.') == std::string::npos;
    if (layer.empty() ? base : c.rfind(layer + ".", 0) == 0) out.push_back(c);
  }
  auto rank = [](const std::string& c) {
    const std::string suffix = c.substr(c.rfind('.') == std::string::npos ? 0 : c.rfind('.') + 1);
    static const std::string order[] = {"R", "G", "B", "A", "X", "Y", "Z"};
    for (int i = 0; i < 7; ++i)
      if (suffix == order[i]) return i;
    return 7;
  };
  std::stable_sort(out.begin(), out.end(), [&](const std::string& a, const std::string& b) {
    return rank(a) != rank(b) ? rank(a) < rank(b) : a < b;
  });
  return out;
}

std::string layer_list(const render::ExrImage& img) {
  std::vector<std::string> names;
  for (const auto& c : img.channels) {
    size_t dot = c.rfind('.');
    std::string n = dot == std::string::npos ? "\"\" (R, G, B)" : c.substr(0, dot);
    if (std::find(names.begin(), names.end(), n) == names.end()) names.push_back(n);
  }
  std::string s;
  for (const auto& n : names) s += (s.empty() ? "" : ", ") + n;
  return s;
}

LayerImage load_layer(const std::string& path, const std::string& layer, const std::vector<std::string>* want,
                      bool require_finite) {
  render::ExrImage img = render::read_exr(path);
  LayerImage li;
  li.width = img.width;
  li.height = img.height;
  li.channels = want ? *want : layer_channels(img, layer);
  const std::string shown = layer.empty() ? "the base layer (R, G, B)" : fmt::format("layer '{}'", layer);
  if (li.channels.empty())
    throw render::Error(fmt::format("{}: no {}; pass --layer with one of: {}", path, shown, layer_list(img)));
  const size_t pixels = size_t(img.width) * img.height;
  li.data.resize(pixels * li.channels.size());
  size_t nonfinite = 0;
  for (size_t c = 0; c < li.channels.size(); ++c) {
    auto it = std::find(img.channels.begin(), img.channels.end(), li.channels[c]);
    if (it == img.channels.end())
      throw render::Error(
          fmt::format("{}: has no channel {} that the reference has; compare images with the same {}", path,
                      li.channels[c], shown));
    const auto& plane = img.data[size_t(it - img.channels.begin())];
    for (size_t p = 0; p < pixels; ++p) {
      li.data[p * li.channels.size() + c] = plane[p];
      if (!std::isfinite(plane[p])) ++nonfinite;
    }
  }
  if (nonfinite && require_finite)
    throw render::Error(fmt::format(
        "{}: {} has {} non-finite values (NaN or Inf); metrics need finite images", path, shown, nonfinite));
  return li;
}

std::vector<std::string> exr_files(const std::string& dir) {
  std::vector<std::string> files;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file() && e.path().extension() == ".exr") files.push_back(e.path().string());
  std::sort(files.begin(), files.end());
  if (files.empty())
    throw render::Error(fmt::format("{}: no .exr files; pass a folder of EXR frames or one .exr", dir));
  return files;
}

// The metrics of one pair (image_metrics) and, when maps is given, the per-pixel FLIP maps (HDR, LDR).
nlohmann::json metrics_of(const Channels& test, const Channels& ref, int width, int height,
                          std::pair<std::vector<float>, std::vector<float>>* maps) {
  nlohmann::json j = compare(test, ref).to_json();
  if (!flip_supports(ref.count)) {
    j["flip_ldr"] = nullptr;
    j["flip_hdr"] = nullptr;
    return j;
  }
  FlipOptions o;
  o.want_map = maps != nullptr;
  FlipResult ldr = flip_ldr(test, ref, width, height, o), hdr = flip_hdr(test, ref, width, height, o);
  j["flip_ldr"] = ldr.mean;
  j["flip_hdr"] = hdr.mean;
  if (maps) *maps = {std::move(hdr.map), std::move(ldr.map)};
  return j;
}

// PATH.exr with flip_hdr.Y and flip_ldr.Y, PATH.png with the HDR-FLIP map through magma.
nlohmann::json write_flip_maps(const std::string& base, int width, int height,
                               const std::pair<std::vector<float>, std::vector<float>>& maps) {
  const std::string exr = base + ".exr", png = base + ".png";
  render::write_exr_channels(exr, width, height, {{"flip_hdr.Y", &maps.first}, {"flip_ldr.Y", &maps.second}});
  render::write_png_rgb8(png, width, height, magma_rgba8(maps.first));
  return {{"exr", exr}, {"png", png}};
}

}  // namespace

nlohmann::json compared_layers(const std::string& test_layer, const std::string& ref_layer) {
  return {{"test", test_layer}, {"reference", ref_layer}};
}

std::string layer_name(const std::string& layer) {
  return layer.empty() ? "R, G, B" : "layer " + layer;
}

std::string layers_text(const nlohmann::json& layers) {
  return fmt::format("test {}, reference {}", layer_name(layers.value("test", "")),
                     layer_name(layers.value("reference", "")));
}

nlohmann::json image_metrics(const Channels& test, const Channels& ref, int width, int height) {
  return metrics_of(test, ref, width, height, nullptr);
}

LayerImage read_layer(const std::string& path, const std::string& layer, bool require_finite) {
  return load_layer(path, layer, nullptr, require_finite);
}

nlohmann::json compare_paths(const std::string& ref, const std::string& test, const std::string& layer,
                             const std::string& flip_map) {
  for (const auto& p : {ref, test})
    if (!fs::exists(p)) throw render::Error(fmt::format("cannot open {}: no such file or folder", p));
  const bool seq = fs::is_directory(ref);
  if (seq != fs::is_directory(test))
    throw render::Error(fmt::format(
        "{} and {}: compare two .exr files or two folders of frames, not one of each", ref, test));
  std::vector<std::string> refs = seq ? exr_files(ref) : std::vector<std::string>{ref};
  std::vector<std::string> tests = seq ? exr_files(test) : std::vector<std::string>{test};
  if (refs.size() != tests.size())
    throw render::Error(fmt::format("{} has {} frames, {} has {}; sequences must have as many frames", test,
                                    tests.size(), ref, refs.size()));
  // --flip-map PATH: a folder for sequences; for one image PATH.exr and PATH.png (an .exr or .png
  // ending given with PATH is dropped).
  std::string map_base = flip_map;
  if (!flip_map.empty()) {
    fs::path p(flip_map);
    if (!seq && (p.extension() == ".exr" || p.extension() == ".png"))
      map_base = p.replace_extension().string();
    render::ensure_writable_dir(seq ? flip_map
                                : fs::path(map_base).parent_path().empty()
                                    ? std::string(".")
                                    : fs::path(map_base).parent_path().string());
  }
  std::vector<LayerImage> r, t;
  nlohmann::json frames = nlohmann::json::array();
  double sum_relmse = 0, sum_smape = 0, sum_mse = 0, sum_flip_ldr = 0, sum_flip_hdr = 0;
  bool has_flip = true;
  for (size_t f = 0; f < refs.size(); ++f) {
    r.push_back(load_layer(refs[f], layer, nullptr, true));
    t.push_back(load_layer(tests[f], layer, &r.back().channels, true));
    const LayerImage &rf = r.back(), &tf = t.back();
    if (tf.width != rf.width || tf.height != rf.height)
      throw render::Error(fmt::format("{} is {}x{}, {} is {}x{}; compare images of one size", tests[f],
                                      tf.width, tf.height, refs[f], rf.width, rf.height));
    has_flip = flip_supports(uint32_t(rf.channels.size()));
    if (!flip_map.empty() && !has_flip)
      throw render::Error(fmt::format("{}: --flip-map needs a layer of 1 or 3 channels, {} has {}", refs[f],
                                      layer.empty() ? "the base layer" : "layer " + layer,
                                      rf.channels.size()));
    std::pair<std::vector<float>, std::vector<float>> maps;
    nlohmann::json m =
        metrics_of(tf.view(), rf.view(), rf.width, rf.height, flip_map.empty() ? nullptr : &maps);
    nlohmann::json frame = {{"reference", refs[f]}, {"test", tests[f]}, {"metrics", m}};
    if (!flip_map.empty())
      frame["flip_map"] =
          write_flip_maps(seq ? (fs::path(flip_map) / fs::path(tests[f]).stem()).string() : map_base,
                          rf.width, rf.height, maps);
    frames.push_back(frame);
    sum_relmse += m["relmse"].get<double>();
    sum_smape += m["smape"].get<double>();
    sum_mse += m["mse"].get<double>();
    if (has_flip) {
      sum_flip_ldr += m["flip_ldr"].get<double>();
      sum_flip_hdr += m["flip_hdr"].get<double>();
    }
  }
  const double n = double(refs.size());
  Metrics mean{sum_relmse / n, sum_smape / n, sum_mse / n, psnr(sum_mse / n)};
  nlohmann::json mean_json = mean.to_json();
  mean_json["flip_ldr"] = has_flip ? nlohmann::json(sum_flip_ldr / n) : nlohmann::json(nullptr);
  mean_json["flip_hdr"] = has_flip ? nlohmann::json(sum_flip_hdr / n) : nlohmann::json(nullptr);
  nlohmann::json j = {{"layer", layer},
                      {"layers", compared_layers(layer, layer)},
                      {"channels", r.front().channels},
                      {"size", {r.front().width, r.front().height}},
                      {"frames", frames},
                      {"mean", mean_json}};
  if (seq && refs.size() > 1) {
    std::vector<Channels> tv, rv;
    for (size_t f = 0; f < refs.size(); ++f) {
      tv.push_back(t[f].view());
      rv.push_back(r[f].view());
    }
    j["temporal"] = temporal(tv, rv).to_json();
  }
  return j;
}

std::string tonemap_exr(const std::string& in, const std::string& layer, double exposure,
                        const std::string& tonemap, const std::string& out) {
  if (!fs::exists(in)) throw render::Error(fmt::format("cannot open {}: no such file", in));
  std::string curve = tonemap, from;
  if (std::isnan(exposure) || curve.empty()) {
    from = ", the default: no stats.json beside it";
    const fs::path stats = fs::path(in).parent_path() / "stats.json";
    nlohmann::json r = nlohmann::json::object();
    if (std::ifstream f(stats); f) {
      nlohmann::json st = nlohmann::json::parse(f, nullptr, false);
      if (!st.is_discarded() && st.contains("scene"))
        r = st["scene"].value("render", r), from = ", the scene's from " + stats.string();
    }
    if (std::isnan(exposure)) exposure = r.value("exposure", 0.0);
    if (curve.empty()) curve = r.value("tonemap", "aces");
  }
  if (curve != "aces" && curve != "reinhard" && curve != "clamp")
    throw render::Error(fmt::format("--tonemap {}: not one of aces, reinhard, clamp", curve));
  LayerImage li = load_layer(in, layer, nullptr, false);
  const size_t pixels = size_t(li.width) * li.height, n = li.channels.size();
  std::vector<float> rgb(pixels * 3, 0.f);
  size_t nonfinite = 0;
  for (size_t p = 0; p < pixels; ++p)
    for (size_t c = 0; c < 3; ++c) {
      const float v = li.data[p * n + (n == 1 ? 0 : c)];
      if (n == 2 && c == 2) continue;
      if (!std::isfinite(v)) {
        nonfinite += n == 1 ? (c == 0) : 1;
        continue;
      }
      rgb[p * 3 + c] = v;
    }
  render::write_png_rgb8(out, li.width, li.height, render::preview_srgb8(rgb, float(exposure), curve));
  std::string line = fmt::format("wrote {} ({} of {}, {} channel{}, {:+g} EV, {}{})\n", out,
                                 layer_name(layer), in, n, n == 1 ? "" : "s", exposure, curve, from);
  if (nonfinite) line += fmt::format("note: {} non-finite values (NaN or Inf) drawn black\n", nonfinite);
  return line;
}

std::string format_comparison(const nlohmann::json& j) {
  auto num = [](const nlohmann::json& v) {
    return v.is_string() ? v.get<std::string>() : fmt::format("{:.6g}", v.get<double>());
  };
  auto line = [&](const nlohmann::json& m) {
    std::string s = fmt::format("relMSE {}  SMAPE {}  MSE {}  PSNR {} dB", num(m["relmse"]), num(m["smape"]),
                                num(m["mse"]), num(m["psnr"]));
    if (m.contains("flip_ldr") && !m["flip_ldr"].is_null())
      s += fmt::format("  FLIP LDR {} HDR {}", num(m["flip_ldr"]), num(m["flip_hdr"]));
    return s;
  };
  std::string s;
  const auto& frames = j["frames"];
  if (frames.size() > 1)
    for (const auto& f : frames)
      s += fmt::format("{}: {}\n", f["test"].get<std::string>(), line(f["metrics"]));
  s += fmt::format("{}{} ({}, {}x{})\n", frames.size() > 1 ? "mean: " : "", line(j["mean"]),
                   layers_text(j["layers"]), j["size"][0].get<int>(), j["size"][1].get<int>());
  for (const auto& f : frames)
    if (f.contains("flip_map"))
      s += fmt::format("FLIP maps: {} {}\n", f["flip_map"]["exr"].get<std::string>(),
                       f["flip_map"]["png"].get<std::string>());
  if (j.contains("temporal"))
    s += fmt::format("temporal: relMSE of the frame-to-frame change {}, change ratio test / reference {}\n",
                     num(j["temporal"]["relmse_of_change"]), num(j["temporal"]["change_ratio"]));
  return s;
}

}  // namespace haze::eval
