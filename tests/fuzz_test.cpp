// A seeded mutation fuzzer over what users hand to haze: scene JSON, --set overrides, .vdb, .obj, image,
// EXR and sweep files. Every case runs the haze command as a user would, under a time and a memory limit,
// and fails on a signal, a hang, an error that is not one line, a valid run whose output is not finite, or
// a failing run that changed the folder's earlier outputs.
//
// HAZE_FUZZ_CASES (default 40, about a minute on lavapipe) and HAZE_FUZZ_SEED (default 1) set the campaign;
// scripts/fuzz.sh runs a long one and prints the counts that docs/reliability.md records.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <stb/stb_image_write.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "render/output.hpp"
#include "scene/scene.hpp"

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr int kTimeoutSeconds =
    150;  // a hang; lavapipe JITs the full-feature trace kernel in ~30 s, more under load
constexpr long kAddressSpaceKiB = 4'000'000;  // ulimit -v: 4 GB, ten times a small render's need
const std::string kSentinel = "an earlier output, never to be replaced by a failing run";

std::string read_file(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

void write_file(const fs::path& p, const std::string& bytes) {
  std::ofstream(p, std::ios::binary) << bytes;
}

int env_int(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v && *v ? std::atoi(v) : fallback;
}

struct Outcome {
  enum Kind { Success, CleanError, Defect } kind;
  std::string why;  // for defects
};

class Fuzzer {
 public:
  Fuzzer(fs::path dir, uint32_t seed) : dir_(std::move(dir)), rng_(seed) {}

  // The valid inputs every mutation starts from.
  void make_seeds() {
    fs::create_directories(dir_);
    const auto r = haze_cmd(fmt::format("vdb make cloud --out {} --voxel-size 0.1 --size 1.2 1.2 1.2",
                                        (dir_ / "cloud.vdb").string()));
    ASSERT_EQ(r.first, 0) << r.second;
    vdb_ = read_file(dir_ / "cloud.vdb");
    obj_ =
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n"
        "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n";
    write_file(dir_ / "quad.obj", obj_);
    std::vector<unsigned char> px(8 * 8 * 3);
    for (size_t i = 0; i < px.size(); ++i) px[i] = static_cast<unsigned char>(37 * i);
    std::string png;
    stbi_write_png_to_func([](void* ctx, void* data,
                              int n) { static_cast<std::string*>(ctx)->append(static_cast<char*>(data), n); },
                           &png, 8, 8, 3, px.data(), 24);
    png_ = png;
    write_file(dir_ / "tex.png", png_);
    scene_ = json::parse(R"({
      "camera": {"position": [0, 0.3, 4], "target": [0, 0.3, 0], "fov_y": 45},
      "media": [{"file": "cloud.vdb", "albedo": [0.8, 0.8, 0.8], "g": 0.3, "density_scale": 2},
                {"procedural": {"kind": "sphere", "voxel_size": 0.1, "center": [1, 0.5, 0], "size": [0.8, 0.8, 0.8]},
                 "emission": {"mode": "scale", "grid": "density", "scale": 0.5}}],
      "haze": {"sigma_t": 0.1, "albedo": [0.9, 0.9, 0.9], "bounded": true,
               "bounds_min": [-3, -1, -3], "bounds_max": [3, 3, 3]},
      "surfaces": [{"file": "quad.obj", "albedo_texture": "tex.png", "transform": {"translate": [0, 0, -1]}},
                   {"mesh": {"kind": "box", "size": [4, 0.1, 4]}, "transform": {"translate": [0, -0.8, 0]},
                    "emission": [0, 0, 0]}],
      "lights": {"sun": {"direction": [0.3, 1, 0.2], "irradiance": 3},
                 "points": [{"position": [-1, 1, 0.5], "intensity": 4}],
                 "environment": {"color": [0.2, 0.3, 0.4]}},
      "guiding": {"enabled": true, "spacing": 4},
      "render": {"width": 16, "height": 12, "spp": 1, "max_depth": 2}
    })");
    write_file(dir_ / "scene.json", scene_.dump(2));
    sweep_ = json::parse(R"({"scene": "scene.json", "axes": [{"path": "render.spp", "values": [1, 2]},
      {"path": "haze.sigma_t", "values": [0.1, 0.2]}], "seeds": 2, "reference": false})");
    for (const auto& p : haze::scene::describe()) {
      std::string path = p.path;
      for (size_t at; (at = path.find("[]")) != std::string::npos;) path.replace(at, 2, "[0]");
      if (p.type.find("object") == std::string::npos) keys_.push_back(path);
    }
    // A valid EXR for haze compare.
    const auto e = haze_cmd(fmt::format("render {} --out {} --set guiding.enabled=false",
                                        (dir_ / "scene.json").string(), (dir_ / "ref").string()));
    ASSERT_EQ(e.first, 0) << e.second;
    exr_ = read_file(dir_ / "ref/frame_0000.exr");
  }

  // One random case; the counts go to `tally`.
  void run_case(int index, std::map<std::string, int>& tally) {
    const fs::path c = dir_ / fmt::format("case_{}", index);
    fs::remove_all(c);
    fs::create_directories(c);
    for (const char* f : {"cloud.vdb", "quad.obj", "tex.png"}) fs::copy_file(dir_ / f, c / f);
    json scene = scene_;
    std::string args, what;
    switch (pick(8)) {
      case 0: {  // the scene file's structure
        mutate_json(scene, 1 + pick(3));
        what = "scene json";
        args = render_args(c, scene.dump(), "");
        break;
      }
      case 7: {  // mostly valid scenes: numbers scaled by up to 100 either way, signs kept
        rescale_numbers(scene);
        what = "scene numbers";
        args = render_args(c, scene.dump(), "");
        break;
      }
      case 1: {  // the scene file's bytes
        std::string text = scene.dump(2);
        mutate_bytes(text, true);
        what = "scene bytes";
        args = render_args(c, text, "");
        break;
      }
      case 2: {  // --set
        std::string sets;
        for (int k = 0, n = 1 + pick(3); k < n; ++k)
          sets += fmt::format(" --set '{}={}'", keys_[pick(keys_.size())], random_value().dump());
        what = "--set";
        args = render_args(c, scene.dump(), sets);
        break;
      }
      case 3: {  // the .vdb file
        std::string v = vdb_;
        mutate_bytes(v, false);
        write_file(c / "cloud.vdb", v);
        what = "vdb bytes";
        args = pick(2) ? fmt::format("vdb info {}", (c / "cloud.vdb").string())
                       : render_args(c, scene.dump(), "");
        break;
      }
      case 4: {  // the .obj or the texture
        if (pick(2)) {
          std::string o = obj_;
          mutate_obj(o);
          write_file(c / "quad.obj", o);
          what = "obj text";
        } else {
          std::string p = png_;
          mutate_bytes(p, false);
          write_file(c / "tex.png", p);
          what = "png bytes";
        }
        args = render_args(c, scene.dump(), "");
        break;
      }
      case 5: {  // a sweep file (checked and listed, not run)
        json s = sweep_;
        mutate_json(s, 1 + pick(2));
        write_file(c / "scene.json", scene.dump());
        write_file(c / "sweep.json", s.dump());
        what = "sweep json";
        args =
            fmt::format("sweep {} --out {} --list", (c / "sweep.json").string(), (c / "sweep_out").string());
        break;
      }
      default: {  // an EXR against a valid one
        std::string e = exr_;
        mutate_bytes(e, false);
        write_file(c / "test.exr", e);
        write_file(c / "ref.exr", exr_);
        what = "exr bytes";
        args = fmt::format("compare {} {}", (c / "ref.exr").string(), (c / "test.exr").string());
        break;
      }
    }
    const Outcome o = judge(c, args);
    ++tally["cases"];
    ++tally[o.kind == Outcome::Success      ? "successes"
            : o.kind == Outcome::CleanError ? "clean errors"
                                            : "defects"];
    if (o.kind == Outcome::Success) ++tally["successes of " + what];
    if (o.kind == Outcome::Defect) {
      ADD_FAILURE() << "case " << index << " (" << what << "): " << o.why << "\n  haze " << args;
    } else {
      fs::remove_all(c);
    }
  }

 private:
  fs::path dir_;
  std::mt19937 rng_;
  std::string vdb_, obj_, png_, exr_;
  json scene_, sweep_;
  std::vector<std::string> keys_;

  size_t pick(size_t n) { return std::uniform_int_distribution<size_t>(0, n - 1)(rng_); }

  // haze with its arguments, under the limits; (exit status, output). 124: timed out; > 128: a signal.
  std::pair<int, std::string> haze_cmd(const std::string& args) const {
    const fs::path log = dir_ / "last.log";
    const std::string cmd =
        fmt::format("bash -c 'ulimit -v {}; exec timeout -s KILL {} {} \"$@\"' haze {} > {} 2>&1",
                    kAddressSpaceKiB, kTimeoutSeconds, HAZE_BIN, args, log.string());
    const int status = std::system(cmd.c_str());
    return {WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status), read_file(log)};
  }

  // A render of `scene_text` in folder c with an earlier output in place.
  std::string render_args(const fs::path& c, const std::string& scene_text, const std::string& sets) {
    write_file(c / "scene.json", scene_text);
    fs::create_directories(c / "out");
    write_file(c / "out/frame_0000.exr", kSentinel);
    write_file(c / "out/stats.json", kSentinel);
    return fmt::format("render {} --out {}{}", (c / "scene.json").string(), (c / "out").string(), sets);
  }

  Outcome judge(const fs::path& c, const std::string& args) const {
    const auto [code, out] = haze_cmd(args);
    if (code == 124 || code == 128 + SIGKILL)
      return {Outcome::Defect, fmt::format("no answer within {} s (or killed)", kTimeoutSeconds)};
    if (code > 128) return {Outcome::Defect, fmt::format("signal {}: {}", code - 128, out)};
    const bool rendered = fs::exists(c / "out");
    if (code == 0) {
      if (rendered) {
        if (read_file(c / "out/frame_0000.exr") == kSentinel)
          return {Outcome::Defect, "exit 0, no new frame"};
        try {
          const auto img = haze::render::read_exr((c / "out/frame_0000.exr").string());
          for (size_t k = 0; k < img.channels.size(); ++k)
            for (float v : img.data[k])
              if (!std::isfinite(v))
                return {Outcome::Defect, "a valid input gave non-finite " + img.channels[k]};
        } catch (const std::exception& e) {
          return {Outcome::Defect, std::string("exit 0 but the EXR does not read: ") + e.what()};
        }
      }
      return {Outcome::Success, ""};
    }
    const size_t at = out.find("haze: error: ");
    if (at == std::string::npos && out.find("Run with --help") == std::string::npos)
      return {Outcome::Defect, fmt::format("exit {} without 'haze: error:': {}", code, out)};
    if (at != std::string::npos && out.find('\n', at) + 1 != out.size())
      return {Outcome::Defect, "the error is not one line: " + out.substr(at)};
    if (rendered &&
        (read_file(c / "out/frame_0000.exr") != kSentinel || read_file(c / "out/stats.json") != kSentinel))
      return {Outcome::Defect, "a failing run replaced an earlier output: " + out};
    if (rendered)
      for (const auto& e : fs::directory_iterator(c / "out"))
        if (e.path().filename().string().find(".tmp") != std::string::npos)
          return {Outcome::Defect, "a failing run left " + e.path().filename().string()};
    return {Outcome::CleanError, ""};
  }

  json random_value() {
    static const std::vector<json> odd = {0,
                                          -1,
                                          1e-30,
                                          1e30,
                                          1e300,
                                          -1e300,
                                          0.5,
                                          7,
                                          65536,
                                          1u << 31,
                                          "x",
                                          "",
                                          "nan",
                                          "inf",
                                          true,
                                          false,
                                          nullptr,
                                          json::array(),
                                          json::object(),
                                          json::array({0, 0, 0}),
                                          json::array({1, "a", 2}),
                                          json::array({1e30, 1e30, 1e30}),
                                          json::array({-1, -1, -1}),
                                          "aces",
                                          "0:3",
                                          "png"};
    return odd[pick(odd.size())];
  }

  // Replaces, deletes, duplicates or adds a value somewhere in `j`.
  void mutate_json(json& j, int times) {
    for (int t = 0; t < times; ++t) {
      json* node = &j;
      for (int depth = 0; depth < 6 && (node->is_object() || node->is_array()) && !node->empty() && pick(4);
           ++depth) {
        if (node->is_object()) {
          auto it = node->begin();
          std::advance(it, long(pick(node->size())));
          node = &it.value();
        } else {
          node = &(*node)[pick(node->size())];
        }
      }
      switch (pick(5)) {
        case 0:
          *node = random_value();
          break;
        case 1:
          if (node->is_number())
            *node = node->get<double>() * std::pow(10.0, double(int(pick(61)) - 30));
          else
            *node = random_value();
          break;
        case 2:
          if (node->is_object() && !node->empty())
            node->erase(node->begin());
          else if (node->is_array() && !node->empty())
            node->erase(node->begin() + long(pick(node->size())));
          else
            *node = random_value();
          break;
        case 3:
          if (node->is_object())
            (*node)["unknown_" + std::to_string(pick(100))] = random_value();
          else if (node->is_array())
            node->push_back(node->empty() ? random_value() : (*node)[0]);
          else
            *node = random_value();
          break;
        default:
          if (node->is_number())
            *node = -node->get<double>();
          else if (node->is_array())
            *node = json::array();
          else
            *node = random_value();
      }
    }
  }

  // Numbers of `j` times 10^u, u uniform in [-1, 0], each with probability 1/3: values shrink within their
  // ranges, so most of these scenes are valid (integers stay integers, and at least 1 when they were).
  void rescale_numbers(json& j) {
    if (j.is_object() || j.is_array()) {
      for (auto& v : j) rescale_numbers(v);
    } else if (j.is_number() && pick(3) == 0) {
      const double k = std::pow(10.0, std::uniform_real_distribution<double>(-1, 0)(rng_));
      const double x = j.get<double>();
      j = j.is_number_float() ? json(x * k) : json(std::max<long long>(std::llround(x * k), x >= 1 ? 1 : 0));
    }
  }

  // Flips, overwrites with 0xff, inserts, deletes or truncates bytes (text: also characters).
  void mutate_bytes(std::string& b, bool text) {
    if (b.empty()) return;
    for (int t = 0, n = 1 + int(pick(4)); t < n; ++t) {
      const size_t at = pick(b.size());
      switch (pick(text ? 5 : 4)) {
        case 0:
          b[at] = char(b[at] ^ (1 << pick(8)));
          break;
        case 1:
          for (size_t k = at; k < std::min(b.size(), at + 1 + pick(8)); ++k) b[k] = '\xff';
          break;
        case 2:
          b.resize(at);
          return;
        case 3:
          b.erase(at, 1 + pick(16));
          break;
        default:
          b.insert(at, std::string(1, "{}[],:\"0e-"[pick(10)]));
      }
      if (b.empty()) return;
    }
  }

  // Replaces numbers of an OBJ with non-numbers, non-finite or huge values, or drops and repeats lines.
  void mutate_obj(std::string& o) {
    std::vector<std::string> lines;
    std::istringstream in(o);
    for (std::string l; std::getline(in, l);) lines.push_back(l);
    static const char* odd[] = {"nan", "inf",  "-inf",  "1e39", "banana",
                                "",    "0x10", "1/2/3", "-0",   "9999999999"};
    for (int t = 0, n = 1 + int(pick(3)); t < n && !lines.empty(); ++t) {
      std::string& l = lines[pick(lines.size())];
      switch (pick(4)) {
        case 0: {
          std::istringstream w(l);
          std::vector<std::string> words;
          for (std::string x; w >> x;) words.push_back(x);
          if (words.size() > 1) words[1 + pick(words.size() - 1)] = odd[pick(10)];
          l.clear();
          for (const auto& x : words) l += x + " ";
          break;
        }
        case 1:
          l = l.substr(0, 1);
          break;
        case 2:
          lines.push_back(l);
          break;
        default:
          l.clear();
      }
    }
    o.clear();
    for (const auto& l : lines) o += l + "\n";
  }
};

TEST(Fuzz, MutatedInputsGiveOneLineErrorsOrFiniteImages) {
  const int cases = env_int("HAZE_FUZZ_CASES", 40);
  const uint32_t seed = uint32_t(env_int("HAZE_FUZZ_SEED", 1));
  const fs::path dir = fs::temp_directory_path() / fmt::format("haze-fuzz-{}-{}", seed, getpid());
  fs::remove_all(dir);
  Fuzzer f(dir, seed);
  f.make_seeds();
  if (HasFatalFailure()) return;
  std::map<std::string, int> tally;
  for (int i = 0; i < cases; ++i) f.run_case(i, tally);
  std::cout << fmt::format("fuzz seed {}: {} cases, {} clean errors, {} successes, {} defects\n", seed,
                           tally["cases"], tally["clean errors"], tally["successes"], tally["defects"]);
  for (const auto& [k, n] : tally)
    if (k.rfind("successes of ", 0) == 0) std::cout << fmt::format("  {} {}\n", n, k);
  EXPECT_EQ(tally["defects"], 0);
  if (tally["defects"] == 0) fs::remove_all(dir);
}

}  // namespace
