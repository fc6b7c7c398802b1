#include "scene/animation.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <functional>
#include <glm/vec3.hpp>
#include <vector>

namespace haze::scene {

// The reflection machinery (reflect/params.hpp) drives reading, writing and overriding scenes.
using namespace reflection;

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

using Segments = std::vector<std::string>;

// Where a track's path leads in one Scene object.
struct Target {
  float* number = nullptr;   // a number, or one component of an [x, y, z]
  glm::vec3* vec = nullptr;  // a whole [x, y, z]
  Constraint constraint;     // of the field: key values must satisfy it
  std::string path;          // canonical JSON path, "media[0].transform.rotate[1]"
  std::string error;         // why the path leads nowhere animatable; "" if it does
  // The objects on the way that have a validate(), innermost first, with their JSON paths: changing the
  // value can break their cross-field rules, so they are checked again per frame.
  std::vector<std::pair<std::string, std::function<void(const ReadContext&)>>> checks;
};

template <class T>
void walk(const Segments& segs, size_t pos, T& value, Target& t);

class FieldFinder : public Visitor<FieldFinder> {
 public:
  FieldFinder(const Segments& segs, size_t pos, Target& t) : segs_(segs), pos_(pos), t_(t) {}
  bool matched = false;
  template <class T>
  void visit(std::string_view name, T& value, const Constraint& c, std::string_view) {
    if (matched || name != segs_[pos_]) return;
    matched = true;
    t_.path = join_path(t_.path, name);
    t_.constraint = c;
    walk(segs_, pos_ + 1, value, t_);
  }

 private:
  const Segments& segs_;
  size_t pos_;
  Target& t_;
};

bool all_digits(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

// Follows segs[pos..] from `value`, whose path is t.path, and records the leaf or the error.
template <class T>
void walk(const Segments& segs, size_t pos, T& value, Target& t) {
  const bool at_end = pos == segs.size();
  const std::string here = t.path;
  auto no_members = [&](size_t at) {
    t.error = fmt::format("{} is a number; it has no member \"{}\"", t.path, segs[at]);
  };
  if constexpr (std::is_same_v<T, float>) {
    if (!at_end) return no_members(pos);
    t.number = &value;
  } else if constexpr (std::is_same_v<T, glm::vec3>) {
    if (at_end) {
      t.vec = &value;
      return;
    }
    const std::string& s = segs[pos];
    if (s != "0" && s != "1" && s != "2") {
      t.error = fmt::format("{} is [x, y, z]; after it comes a component 0, 1 or 2, not \"{}\"", t.path, s);
      return;
    }
    t.path += "[" + s + "]";
    if (pos + 1 != segs.size()) return no_members(pos + 1);
    t.number = &value[s[0] - '0'];
  } else if constexpr (Reflectable<T>) {
    if (at_end) {
      t.error = fmt::format("{} is an object; animate one of its numbers or [x, y, z] vectors", t.path);
      return;
    }
    FieldFinder finder(segs, pos, t);
    reflect(finder, value);
    if (!finder.matched) {
      reflection::detail::KeyList keys;
      reflect(keys, value);
      t.error = fmt::format("{}: {}", join_path(here, segs[pos]),
                            reflection::detail::unknown_key_message(segs[pos], keys.names));
      return;
    }
    if constexpr (Validated<T>) {
      if (t.error.empty()) {
        t.checks.emplace_back(here,
                              [&value, here](const ReadContext& ctx) { validate(value, Where(ctx, here)); });
      }
    }
  } else if constexpr (ReflectableOptional<T>) {
    if (!at_end && !value) {
      t.error = fmt::format("{} is not in the scene; add it to animate its members", t.path);
      return;
    }
    if (at_end) {
      t.error = fmt::format("{} is an object; animate one of its numbers or [x, y, z] vectors", t.path);
      return;
    }
    walk(segs, pos, *value, t);
  } else if constexpr (ReflectableVector<T>) {
    if (at_end) {
      t.error = fmt::format("{} is a list; animate a number or [x, y, z] of one element, e.g. {}[0]...",
                            t.path, t.path);
      return;
    }
    const std::string& s = segs[pos];
    if (!all_digits(s) || s.size() > 9) {
      t.error = fmt::format("{} is a list; after it comes an element index, not \"{}\"", t.path, s);
      return;
    }
    size_t i = std::stoul(s);
    if (i >= value.size()) {
      t.error = value.empty() ? fmt::format("{} is empty, so it has no element {}", t.path, i)
                              : fmt::format("{} has {} element{}; there is no {}[{}]", t.path, value.size(),
                                            value.size() == 1 ? "" : "s", t.path, i);
      return;
    }
    t.path += "[" + s + "]";
    walk(segs, pos + 1, value[i], t);
  } else if constexpr (std::is_same_v<T, json> || std::is_same_v<T, std::optional<json>>) {
    t.error = fmt::format("{} is free-form JSON and cannot be animated", t.path);
  } else {
    std::string type = reflection::detail::type_name<T>();
    const char* article = std::string_view("aeiou").find(type[0]) == std::string_view::npos ? "a" : "an";
    t.error =
        fmt::format("{} is {} {}; only numbers and [x, y, z] vectors can be animated", t.path, article, type);
  }
}

// One track, resolved against one Scene object.
struct Compiled {
  size_t index = 0;  // in animation.tracks
  Target target;
  bool smooth = false;
  std::vector<double> frames;
  std::vector<glm::vec3> values;  // numbers in .x
};

// `a` is `b` or inside it: "camera.position[1]" is inside "camera.position" and "camera", not "camera.p".
bool inside(std::string_view a, std::string_view b) {
  if (b.empty()) return true;
  return a.size() >= b.size() && a.compare(0, b.size(), b) == 0 &&
         (a.size() == b.size() || a[b.size()] == '.' || a[b.size()] == '[');
}

// Resolves every track against `s` (pointers into it) and reads its keys; throws Error naming the
// animation's JSON path.
std::vector<Compiled> compile(Scene& s, const ReadContext& ctx) {
  std::vector<Compiled> out;
  if (!s.animation) return out;
  auto& tracks = s.animation->tracks;
  for (size_t i = 0; i < tracks.size(); ++i) {
    Track& track = tracks[i];
    const std::string at = fmt::format("animation.tracks[{}]", i);
    // Reading checked these already; again for scenes built in code.
    for (size_t k = 0; k < track.keys.size(); ++k)
      validate(track.keys[k], Where(ctx, fmt::format("{}.keys[{}]", at, k)));
    validate(track, Where(ctx, at));
    const std::string path_at = at + ".path";
    Segments segs;
    if (std::string why = reflection::detail::split_path(track.path, segs); !why.empty()) {
      ctx.fail(path_at,
               fmt::format("\"{}\" has {}; write it as a.b.c, e.g. camera.position or media[0].albedo",
                           track.path, why));
    }
    if (segs[0] == "animation") ctx.fail(path_at, "the animation cannot animate itself");
    Compiled c;
    c.index = i;
    c.smooth = track.interpolation == "smooth";
    walk(segs, 0, s, c.target);
    if (!c.target.error.empty()) ctx.fail(path_at, fmt::format("\"{}\": {}", track.path, c.target.error));
    if (c.target.path == "render.fps")
      ctx.fail(path_at, "render.fps is the time base and cannot be animated");
    for (const Compiled& other : out) {
      if (inside(c.target.path, other.target.path) || inside(other.target.path, c.target.path)) {
        ctx.fail(path_at,
                 fmt::format("animates {}, which animation.tracks[{}] already animates ({}); use one "
                             "track per value",
                             c.target.path, other.index, other.target.path));
      }
    }
    for (size_t k = 0; k < track.keys.size(); ++k) {
      const std::string value_at = fmt::format("{}.keys[{}].value", at, k);
      c.frames.push_back(track.keys[k].frame);
      if (c.target.vec) {
        c.values.push_back(
            reflection::detail::read_vec3(track.keys[k].value, c.target.constraint, ctx, value_at));
      } else {
        double x =
            reflection::detail::read_number(track.keys[k].value, c.target.constraint, true, ctx, value_at);
        c.values.emplace_back(static_cast<float>(x), 0.f, 0.f);
      }
    }
    out.push_back(std::move(c));
  }
  return out;
}

double sign(double x) {
  return x > 0 ? 1 : x < 0 ? -1 : 0;
}

// Slope of the smooth curve at key k, component i: Steffen's monotone choice (M. Steffen, "A simple
// method for monotonic interpolation in one dimension", A&A 239, 1990), zero at local extrema and at the
// first and last key, so that the curve joins the holds smoothly and never leaves the range of the two
// keys around it.
double slope(const Compiled& c, size_t k, int i) {
  if (k == 0 || k + 1 == c.frames.size()) return 0;
  double h0 = c.frames[k] - c.frames[k - 1], h1 = c.frames[k + 1] - c.frames[k];
  double d0 = (c.values[k][i] - c.values[k - 1][i]) / h0;
  double d1 = (c.values[k + 1][i] - c.values[k][i]) / h1;
  double p = (d0 * h1 + d1 * h0) / (h0 + h1);
  return (sign(d0) + sign(d1)) * std::min({std::abs(d0), std::abs(d1), 0.5 * std::abs(p)});
}

glm::vec3 sample(const Compiled& c, double frame) {
  if (frame <= c.frames.front()) return c.values.front();
  if (frame >= c.frames.back()) return c.values.back();
  size_t k =
      static_cast<size_t>(std::upper_bound(c.frames.begin(), c.frames.end(), frame) - c.frames.begin()) - 1;
  double h = c.frames[k + 1] - c.frames[k];
  double s = (frame - c.frames[k]) / h, s2 = s * s, s3 = s2 * s;
  glm::vec3 out;
  for (int i = 0; i < 3; ++i) {
    double y0 = c.values[k][i], y1 = c.values[k + 1][i], y;
    if (c.smooth) {
      // Cubic Hermite; with both slopes zero this is smoothstep, 3s^2 - 2s^3.
      y = (2 * s3 - 3 * s2 + 1) * y0 + (s3 - 2 * s2 + s) * h * slope(c, k, i) + (3 * s2 - 2 * s3) * y1 +
          (s3 - s2) * h * slope(c, k + 1, i);
    } else {
      y = y0 + (y1 - y0) * s;
    }
    // The curve stays between the two keys in exact arithmetic; clamping makes it so in floats too, so
    // every range that holds at the keys holds in between.
    float lo = std::min(c.values[k][i], c.values[k + 1][i]),
          hi = std::max(c.values[k][i], c.values[k + 1][i]);
    out[i] = std::clamp(static_cast<float>(y), lo, hi);
  }
  return out;
}

std::string origin_of(const Scene& s) {
  return s.path.empty() ? "<memory>" : s.path;
}

Scene evaluate(const Scene& s, int frame, const ReadContext& base) {
  Scene out = s;
  if (!is_animated(s)) return out;
  ReadContext ctx{fmt::format("{}: frame {}", base.origin, frame), base.overrides};
  std::vector<Compiled> tracks = compile(out, ctx);
  for (const Compiled& c : tracks) {
    glm::vec3 v = sample(c, frame);
    if (c.target.vec)
      *c.target.vec = v;
    else
      *c.target.number = v.x;
  }
  // Check each changed object once, after all tracks are applied (position and target may move
  // together), innermost first as when reading.
  struct Check {
    std::string path;
    const std::function<void(const ReadContext&)>* run;
  };
  std::vector<Check> checks;
  for (const Compiled& c : tracks) {
    for (const auto& check : c.target.checks) {
      const std::string& path = check.first;  // named, not bound: clang 14 lambdas cannot capture bindings
      const auto& run = check.second;
      bool seen = std::any_of(checks.begin(), checks.end(), [&](const Check& k) { return k.path == path; });
      if (!seen) checks.push_back({path, &run});
    }
  }
  auto depth = [](const std::string& p) {
    return std::count(p.begin(), p.end(), '.') + std::count(p.begin(), p.end(), '[');
  };
  std::stable_sort(checks.begin(), checks.end(),
                   [&](const Check& a, const Check& b) { return depth(a.path) > depth(b.path); });
  for (const Check& check : checks) {
    try {
      (*check.run)(ctx);
    } catch (const Error& e) {
      // Name the tracks that moved this object: the rule may involve a value no track touches.
      std::string by;
      for (const Compiled& c : tracks) {
        if (inside(c.target.path, check.path))
          by += fmt::format("{}animation.tracks[{}]", by.empty() ? "" : ", ", c.index);
      }
      throw Error(fmt::format("{} (animated by {})", e.what(), by));
    }
  }
  for (Medium& m : out.media) {
    if (is_sequence(m.file)) m.file = frame_file(m.file, frame);
  }
  out.animation.reset();
  return out;
}

}  // namespace

bool is_sequence(std::string_view file) {
  return file.find('#') != std::string_view::npos;
}

std::string frame_file(std::string_view pattern, int frame) {
  size_t begin = pattern.find('#');
  if (begin == std::string_view::npos) return std::string(pattern);
  size_t end = pattern.find_first_not_of('#', begin);
  if (end == std::string_view::npos) end = pattern.size();
  return fmt::format("{}{:0{}d}{}", pattern.substr(0, begin), frame, end - begin, pattern.substr(end));
}

bool is_animated(const Scene& s) {
  if (s.animation && !s.animation->tracks.empty()) return true;
  return std::any_of(s.media.begin(), s.media.end(), [](const Medium& m) { return is_sequence(m.file); });
}

Scene scene_at_frame(const Scene& s, int frame) {
  return evaluate(s, frame, ReadContext{origin_of(s), {}});
}

std::pair<int, int> frame_range(const Scene& s) {
  if (!s.render.frames.empty()) {
    std::pair<int, int> range;
    std::string error;
    if (!detail::parse_frame_range(s.render.frames, range, error)) {
      throw Error(fmt::format("{}: render.frames: {}", origin_of(s), error));
    }
    return range;
  }
  if (!s.animation) return {0, 0};
  int first = kMaxFrame + 1, last = -1;
  for (const Track& t : s.animation->tracks) {
    if (t.keys.empty()) continue;
    first = std::min(first, t.keys.front().frame);
    last = std::max(last, t.keys.back().frame);
  }
  if (last < 0) return {0, 0};
  return {std::max(first, 0), last};
}

std::pair<int, int> parse_frames(std::string_view text) {
  std::pair<int, int> range;
  std::string error;
  if (!detail::parse_frame_range(text, range, error))
    throw Error(fmt::format("--frames {}: {}", text, error));
  return range;
}

double frame_time(const Scene& s, int frame) {
  return frame / static_cast<double>(s.render.fps);
}

void check_frame_files(const Scene& s, int first, int last) {
  detail::check_frame_files(s, first, last, ReadContext{origin_of(s), {}});
}

namespace detail {

bool parse_frame_range(std::string_view text, std::pair<int, int>& range, std::string& error) {
  auto trim = [](std::string_view v) {
    while (!v.empty() && std::isspace(static_cast<unsigned char>(v.front()))) v.remove_prefix(1);
    while (!v.empty() && std::isspace(static_cast<unsigned char>(v.back()))) v.remove_suffix(1);
    return v;
  };
  const std::string_view usage = "write A:B with both frames included, e.g. 0:119, or one frame A";
  std::string_view t = trim(text);
  if (t.empty()) {
    error = fmt::format("is empty; {}", usage);
    return false;
  }
  size_t colon = t.find(':');
  std::string_view parts[2] = {t.substr(0, colon),
                               colon == std::string_view::npos ? t.substr(0, colon) : t.substr(colon + 1)};
  if (colon != std::string_view::npos && parts[1].find(':') != std::string_view::npos) {
    error = fmt::format("has more than one ':'; {}", usage);
    return false;
  }
  int frames[2];
  for (int i = 0; i < 2; ++i) {
    std::string_view p = trim(parts[i]);
    if (p.size() > 1 && p[0] == '-' && all_digits(p.substr(1))) {
      error = fmt::format("frames start at 0, got {}", p);
      return false;
    }
    if (!all_digits(p)) {
      error = p.empty() ? fmt::format("a frame number is missing; {}", usage)
                        : fmt::format("expected a frame number, got \"{}\"; {}", p, usage);
      return false;
    }
    if (p.size() > 7 || std::stol(std::string(p)) > kMaxFrame) {
      error = fmt::format("frame {} is too large; frames go up to {}", p, kMaxFrame);
      return false;
    }
    frames[i] = std::stoi(std::string(p));
  }
  if (frames[0] > frames[1]) {
    error = fmt::format("the first frame ({}) is after the last ({}); write A:B with A <= B", frames[0],
                        frames[1]);
    return false;
  }
  range = {frames[0], frames[1]};
  return true;
}

void check_animation(const Scene& s, const ReadContext& ctx) {
  if (!is_animated(s)) return;
  // Paths and key values first, without a frame in the messages: they are wrong at every frame.
  Scene copy = s;
  if (compile(copy, ctx).empty()) return;  // sequences only: nothing to check per frame
  auto [first, last] = frame_range(s);
  // Outside the keys every track holds, so those frames equal the first or last keyed one: a long
  // render.frames around a short animation costs no more than the animation.
  Scene keys_only = s;
  keys_only.render.frames.clear();
  auto [key_first, key_last] = frame_range(keys_only);
  int from = std::max(first, key_first), to = std::min(last, key_last);
  if (from > to) from = to = first;  // the range misses the keys: all its frames are one hold
  for (int f = from; f <= to; ++f) evaluate(s, f, ctx);
}

void check_frame_files(const Scene& s, int first, int last, const ReadContext& ctx) {
  std::error_code ec;
  for (size_t i = 0; i < s.media.size(); ++i) {
    const std::string& pattern = s.media[i].file;
    if (!is_sequence(pattern)) continue;
    for (int f = first; f <= last; ++f) {
      std::string file = frame_file(pattern, f);
      if (!fs::is_regular_file(file, ec)) {
        ctx.fail(fmt::format("media[{}].file", i),
                 fmt::format("frame {}: no such file: {} (the sequence {} is read for frames {}..{}; render "
                             "only the frames that exist with render.frames or --frames)",
                             f, file, pattern, first, last));
      }
    }
  }
}

}  // namespace detail

}  // namespace haze::scene
