#include "reflect/params.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cfloat>
#include <cmath>
#include <cstdlib>
#include <set>

namespace haze::reflection {

using nlohmann::json;

namespace {

std::string num(double x) {
  return fmt::format("{}", x);
}

std::string quoted_list(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "\"" : ", \"") + n + "\"";
  return out;
}

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

// Optimal string alignment distance: edits plus adjacent transpositions ("witdh" -> "width" is 1).
size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::vector<size_t>> d(a.size() + 1, std::vector<size_t>(b.size() + 1));
  for (size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    for (size_t j = 1; j <= b.size(); ++j) {
      size_t cost = a[i - 1] == b[j - 1] ? 0 : 1;
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + cost});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) {
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
      }
    }
  }
  return d[a.size()][b.size()];
}

// The closest name if it is close enough to be a plausible typo, else "".
std::string suggest(std::string_view key, const std::vector<std::string>& names) {
  std::string k = lower(key), best;
  size_t best_d = std::max<size_t>(1, key.size() / 3) + 1;
  for (const auto& n : names) {
    size_t d = edit_distance(k, lower(n));
    if (d < best_d) best_d = d, best = n;
  }
  return best;
}

// A short rendering of a JSON value for "got ..." in messages; never more than one line.
std::string brief(const json& j) {
  if (j.is_object()) return "an object";
  if (j.is_array()) return fmt::format("an array of {} element{}", j.size(), j.size() == 1 ? "" : "s");
  std::string s = j.dump();
  if (s.size() > 60) s = s.substr(0, 57) + "...";
  return s;
}

// Parses the whole of `text` as a number; nullopt if it is not one. Accepts "nan" and "inf" so that the
// caller can say why they are refused.
std::optional<double> parse_double(std::string_view text) {
  std::string s(text);
  if (s.empty()) return std::nullopt;
  char* end = nullptr;
  double x = std::strtod(s.c_str(), &end);
  if (end != s.c_str() + s.size()) return std::nullopt;
  return x;
}

std::string trim(std::string_view s) {
  size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return std::string(s.substr(b, e - b));
}

bool all_digits(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

}  // namespace

bool Range::contains(double x) const {
  return (lo_open ? x > lo : x >= lo) && (hi_open ? x < hi : x <= hi);
}

std::string Range::text() const {
  bool has_lo = std::isfinite(lo), has_hi = std::isfinite(hi);
  if (has_lo && has_hi) {
    return fmt::format("in {}{}, {}{}", lo_open ? "(" : "[", num(lo), num(hi), hi_open ? ")" : "]");
  }
  if (has_lo) return fmt::format("{} {}", lo_open ? ">" : ">=", num(lo));
  if (has_hi) return fmt::format("{} {}", hi_open ? "<" : "<=", num(hi));
  return {};
}

bool Choices::contains(std::string_view s) const {
  return std::find(names.begin(), names.end(), s) != names.end();
}

std::string Choices::text() const {
  return "one of " + quoted_list(names);
}

std::string Constraint::text() const {
  if (range) return range->text();
  if (choices) return choices->text();
  return {};
}

std::string join_path(std::string_view path, std::string_view key) {
  if (path.empty()) return std::string(key);
  if (key.empty()) return std::string(path);
  if (key.front() == '[') return std::string(path) + std::string(key);
  return std::string(path) + "." + std::string(key);
}

void ReadContext::fail(std::string_view path, std::string_view what) const {
  std::string msg = fmt::format("{}: {}: {}", origin.empty() ? "<memory>" : origin,
                                path.empty() ? "(top level)" : path, what);
  // Name the --set that put the bad value there, if any did: the last one to touch it.
  for (auto it = overrides.rbegin(); it != overrides.rend(); ++it) {
    const auto& [p, assignment] = *it;
    bool under = path.size() >= p.size() && path.compare(0, p.size(), p) == 0 &&
                 (path.size() == p.size() || path[p.size()] == '.' || path[p.size()] == '[');
    if (under) {
      msg += fmt::format(" (value from --set {})", assignment);
      break;
    }
  }
  throw Error(msg);
}

namespace {

// SAX events of nlohmann::json, tracking the path and the keys of every open object.
class DuplicateKeys : public nlohmann::json_sax<json> {
 public:
  std::string found;  // path of the first repeated key

  bool key(string_t& k) override {
    Frame& f = frames_.back();
    f.key = k;
    if (!f.keys.insert(k).second && found.empty()) found = join_path(f.path, k);
    return found.empty();
  }
  bool start_object(std::size_t) override { return open(); }
  bool end_object() override { return close(); }
  bool start_array(std::size_t) override {
    open();
    frames_.back().array = true;
    return true;
  }
  bool end_array() override { return close(); }
  bool null() override { return value(); }
  bool boolean(bool) override { return value(); }
  bool number_integer(number_integer_t) override { return value(); }
  bool number_unsigned(number_unsigned_t) override { return value(); }
  bool number_float(number_float_t, const string_t&) override { return value(); }
  bool string(string_t&) override { return value(); }
  bool binary(binary_t&) override { return value(); }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception&) override {
    return false;
  }

 private:
  struct Frame {
    std::string path;
    bool array = false;
    size_t index = 0;
    std::string key;
    std::set<std::string> keys;
  };
  std::vector<Frame> frames_;
  // Where the value that starts now sits.
  std::string here() const {
    if (frames_.empty()) return "";
    const Frame& f = frames_.back();
    return f.array ? join_path(f.path, fmt::format("[{}]", f.index)) : join_path(f.path, f.key);
  }
  bool open() {
    Frame f;
    f.path = here();
    frames_.push_back(std::move(f));
    return true;
  }
  bool close() {
    frames_.pop_back();
    return value();
  }
  bool value() {
    if (!frames_.empty() && frames_.back().array) ++frames_.back().index;
    return true;
  }
};

}  // namespace

namespace {

// Line and column of a byte offset, for parse errors.
std::pair<size_t, size_t> line_column(const std::string& text, size_t byte) {
  size_t line = 1, column = 1;
  for (size_t i = 0; i < byte && i < text.size(); ++i) {
    if (text[i] == '\n')
      line++, column = 1;
    else
      column++;
  }
  return {line, column};
}

}  // namespace

json parse_json(const std::string& text, const std::string& origin) {
  json j;
  try {
    // Comments are allowed: these files are written by hand.
    j = json::parse(text, nullptr, /*allow_exceptions=*/true, /*ignore_comments=*/true);
  } catch (const json::parse_error& e) {
    auto [line, column] = line_column(text, e.byte == 0 ? 0 : e.byte - 1);
    // nlohmann's message starts with "[json.exception.parse_error.101] parse error at line L, column C: ";
    // keep only the part after it, since the position is printed in our own format.
    std::string what = e.what();
    if (auto colon = what.find(": "); colon != std::string::npos) what = what.substr(colon + 2);
    std::replace(what.begin(), what.end(), '\n', ' ');
    throw Error(fmt::format("{}: line {}, column {}: malformed JSON: {}; fix the syntax there", origin, line,
                            column, what));
  } catch (const json::exception& e) {
    // Number overflow (1e999) is reported as out_of_range, without a position.
    std::string what = e.what();
    if (auto bracket = what.find("] "); bracket != std::string::npos) what = what.substr(bracket + 2);
    throw Error(fmt::format("{}: malformed JSON: {}; fix the value", origin, what));
  }
  if (std::string dup = duplicate_key(text); !dup.empty())
    throw Error(fmt::format("{}: {}: the key appears twice in one object; keep one", origin, dup));
  return j;
}

std::string duplicate_key(const std::string& text, bool ignore_comments) {
  DuplicateKeys sax;
  json::sax_parse(text, &sax, json::input_format_t::json, /*strict=*/true, ignore_comments);
  return sax.found;
}

std::string format_params(const std::vector<ParamInfo>& params) {
  size_t w = 0;
  for (const auto& p : params) w = std::max(w, p.path.size());
  std::string out;
  for (const auto& p : params) {
    std::string details = p.type;
    if (!p.default_value.empty()) details += ", default " + p.default_value;
    if (!p.constraint.empty()) details += ", " + p.constraint;
    out += fmt::format("{:<{}}  {} ({})\n", p.path, w, p.help, details);
  }
  return out;
}

namespace detail {

bool read_bool(const json& j, const ReadContext& ctx, const std::string& path) {
  if (!j.is_boolean()) ctx.fail(path, "expected true or false, got " + brief(j));
  return j.get<bool>();
}

double read_number(const json& j, const Constraint& c, bool as_float, const ReadContext& ctx,
                   const std::string& path) {
  if (!j.is_number()) ctx.fail(path, "expected a number, got " + brief(j));
  double x = j.get<double>();
  if (!std::isfinite(x)) ctx.fail(path, "must be a finite number, got " + num(x));
  if (as_float && std::abs(x) > FLT_MAX) ctx.fail(path, "is too large for a 32-bit float, got " + num(x));
  if (c.range && !c.range->contains(x))
    ctx.fail(path, fmt::format("must be {}, got {}", c.range->text(), num(x)));
  return x;
}

long long read_integer(const json& j, const Constraint& c, long long lo, long long hi, const ReadContext& ctx,
                       const std::string& path) {
  long long v = 0;
  if (j.is_number_unsigned()) {
    uint64_t u = j.get<uint64_t>();
    if (u > static_cast<uint64_t>(hi)) ctx.fail(path, fmt::format("must be at most {}, got {}", hi, u));
    v = static_cast<long long>(u);
  } else if (j.is_number_integer()) {
    v = j.get<int64_t>();
  } else if (j.is_number_float()) {
    // 64.0 or 1e3 are integers written as floats; accept them, refuse 2.5.
    double x = j.get<double>();
    if (!std::isfinite(x)) ctx.fail(path, "must be a finite number, got " + num(x));
    if (x != std::floor(x) || std::abs(x) > 9e15) ctx.fail(path, "expected an integer, got " + num(x));
    v = static_cast<long long>(x);
  } else {
    ctx.fail(path, "expected an integer, got " + brief(j));
  }
  if (v < lo || v > hi) ctx.fail(path, fmt::format("must be in [{}, {}], got {}", lo, hi, v));
  if (c.range && !c.range->contains(static_cast<double>(v))) {
    ctx.fail(path, fmt::format("must be {}, got {}", c.range->text(), v));
  }
  return v;
}

std::string read_string(const json& j, const Constraint& c, const ReadContext& ctx, const std::string& path) {
  if (!j.is_string()) ctx.fail(path, "expected a string, got " + brief(j));
  std::string s = j.get<std::string>();
  if (c.choices && !c.choices->contains(s)) {
    std::string guess = suggest(s, c.choices->names);
    ctx.fail(path, fmt::format("must be {}, got \"{}\"{}", c.choices->text(), s,
                               guess.empty() ? "" : " (did you mean \"" + guess + "\"?)"));
  }
  return s;
}

glm::vec3 read_vec3(const json& j, const Constraint& c, const ReadContext& ctx, const std::string& path) {
  if (!j.is_array() || j.size() != 3)
    ctx.fail(path, "expected an array of 3 numbers [x, y, z], got " + brief(j));
  glm::vec3 v;
  for (int i = 0; i < 3; ++i) {
    v[i] = static_cast<float>(read_number(j[i], c, true, ctx, fmt::format("{}[{}]", path, i)));
  }
  return v;
}

std::vector<std::string> read_string_list(const json& j, const Constraint& c, const ReadContext& ctx,
                                          const std::string& path) {
  expect_array(j, ctx, path, "strings");
  std::vector<std::string> out;
  for (size_t i = 0; i < j.size(); ++i)
    out.push_back(read_string(j[i], c, ctx, fmt::format("{}[{}]", path, i)));
  return out;
}

void expect_object(const json& j, const ReadContext& ctx, const std::string& path) {
  if (!j.is_object()) ctx.fail(path, "expected an object {...}, got " + brief(j));
}

void expect_array(const json& j, const ReadContext& ctx, const std::string& path, std::string_view what) {
  if (!j.is_array()) ctx.fail(path, fmt::format("expected an array of {} [...], got {}", what, brief(j)));
}

std::string unknown_key_message(std::string_view key, const std::vector<std::string>& names) {
  std::string guess = suggest(key, names);
  if (!guess.empty()) return "unknown key (did you mean \"" + guess + "\"?)";
  return "unknown key; expected one of " + quoted_list(names);
}

void check_keys(const json& j, const std::vector<std::string>& names, const ReadContext& ctx,
                const std::string& path) {
  for (const auto& item : j.items()) {
    if (std::find(names.begin(), names.end(), item.key()) == names.end()) {
      ctx.fail(join_path(path, item.key()), unknown_key_message(item.key(), names));
    }
  }
}

json write_float(float f) {
  // fmt prints the shortest text that reads back as the same float, so 0.9f is written as 0.9 and not
  // as 0.8999999761581421: stats.json stays readable and reading it back gives the same float.
  return std::strtod(fmt::format("{}", f).c_str(), nullptr);
}

json write_vec3(const glm::vec3& v) {
  return json::array({write_float(v.x), write_float(v.y), write_float(v.z)});
}

std::string split_path(std::string_view path, std::vector<std::string>& segs) {
  // Keys joined by '.', each optionally followed by [index] groups: media.0.g, and the bracket form that
  // error messages print, media[0].g. Anything else ("media[0.g", "media[0]].g") is refused, not guessed.
  const std::string p = trim(path);
  segs.clear();
  size_t i = 0;
  bool need_key = true;  // at the start and after a '.'
  while (i < p.size()) {
    if (p[i] == '[') {
      if (segs.empty()) return "an index [n] must follow a key";
      size_t close = p.find(']', i);
      const std::string index =
          p.substr(i + 1, close == std::string::npos ? std::string::npos : close - i - 1);
      if (close == std::string::npos || index.empty() || index.find_first_of("[.") != std::string::npos)
        return "a '[' without its index and ']'";
      segs.push_back(index);
      i = close + 1;
      if (i < p.size() && p[i] != '.' && p[i] != '[') return "a ']' must be followed by '.', '[' or the end";
      need_key = false;
      continue;
    }
    if (p[i] == ']') return "a ']' without its '['";
    if (p[i] == '.') {
      if (need_key) return "an empty part";
      ++i;
      need_key = true;
      if (i == p.size()) return "an empty part";
      continue;
    }
    size_t end = p.find_first_of(".[]", i);
    if (end == std::string::npos) end = p.size();
    if (!need_key) return "a key must follow a '.'";
    segs.push_back(p.substr(i, end - i));
    i = end;
    need_key = false;
  }
  if (segs.empty()) return "an empty part";
  return "";
}

Override parse_assignment(std::string_view assignment, std::string_view origin, std::string& value) {
  Override o;
  o.assignment = std::string(assignment);
  o.origin = origin.empty() ? "<memory>" : std::string(origin);
  size_t eq = assignment.find('=');
  if (eq == std::string_view::npos) {
    throw Error(fmt::format("{}: --set {}: expected dotted.path=value, for example render.spp=64", o.origin,
                            assignment));
  }
  value = trim(assignment.substr(eq + 1));
  std::string path = trim(assignment.substr(0, eq));
  if (std::string why = split_path(path, o.segs); !why.empty()) {
    throw Error(fmt::format("{}: --set {}: the path \"{}\" has {}; write it as a.b.c or a[0].b", o.origin,
                            assignment, path, why));
  }
  return o;
}

void override_fail(const Override& o, std::string_view path, std::string_view what) {
  throw Error(fmt::format("{}: {}: {} (in --set {})", o.origin, path.empty() ? "(top level)" : path, what,
                          o.assignment));
}

long long parse_index(const Override& o, size_t pos, long long limit) {
  const std::string& s = o.segs[pos];
  if (!all_digits(s) || s.size() > 9) {
    override_fail(o, o.json_path, fmt::format("expected an element index after it, got \"{}\"", s));
  }
  long long i = std::stoll(s);
  if (limit >= 0 && i >= limit) {
    override_fail(o, o.json_path, fmt::format("index {} is out of range; use 0..{}", i, limit - 1));
  }
  return i;
}

namespace {

// The JSON that --set's value text stands for, given what the schema expects there.
json override_value(const Override& o, std::string_view text) {
  json parsed = json::parse(text, nullptr, /*allow_exceptions=*/false);
  const bool is_json = !parsed.is_discarded();
  switch (o.target) {
    case Target::String:
      // Strings need no quotes: media.0.grid=density, and media.0.grid=123 means the string "123".
      return is_json && parsed.is_string() ? parsed : json(std::string(text));
    case Target::StringList:
      if (is_json && parsed.is_array()) return parsed;
      if (is_json && parsed.is_string()) return json::array({parsed});
      {
        // render.outputs=exr,png
        json out = json::array();
        std::string s(text);
        size_t start = 0;
        while (true) {
          size_t comma = s.find(',', start);
          std::string item =
              trim(s.substr(start, comma == std::string::npos ? std::string::npos : comma - start));
          if (!item.empty()) out.push_back(item);
          if (comma == std::string::npos) break;
          start = comma + 1;
        }
        return out;
      }
    case Target::Integer:
    case Target::Number:
      if (is_json && parsed.is_number()) return parsed;
      if (auto x = parse_double(text); x && !std::isfinite(*x)) {
        override_fail(o, o.json_path, fmt::format("must be a finite number, got {}", text));
      }
      override_fail(o, o.json_path, fmt::format("expected a number, got \"{}\"", text));
    case Target::Vec3:
      if (is_json) return parsed;
      {
        // camera.position=0,1,5
        json out = json::array();
        std::string s(text);
        size_t start = 0;
        while (true) {
          size_t comma = s.find(',', start);
          std::string item =
              trim(s.substr(start, comma == std::string::npos ? std::string::npos : comma - start));
          auto x = parse_double(item);
          if (!x) {
            override_fail(o, o.json_path, fmt::format("expected [x, y, z] or x,y,z, got \"{}\"", text));
          }
          if (!std::isfinite(*x)) {
            override_fail(o, o.json_path, fmt::format("must be finite numbers, got {}", item));
          }
          out.push_back(*x);
          if (comma == std::string::npos) break;
          start = comma + 1;
        }
        return out;
      }
    default:
      // Bool, objects and free-form JSON: anything that is not JSON is taken as a string and the reader
      // then says what it expected.
      return is_json ? parsed : json(std::string(text));
  }
}

}  // namespace

void set_override(json& root, const Override& o, std::string_view value_text) {
  json value = override_value(o, value_text);
  if (root.is_null()) root = json::object();
  json* node = &root;
  std::string path;
  for (size_t i = 0; i < o.segs.size(); ++i) {
    const std::string& seg = o.segs[i];
    Step step = o.steps[i];
    if (step == Step::Free) step = node->is_array() && all_digits(seg) ? Step::Index : Step::Key;
    if (step == Step::Key) {
      if (node->is_null()) *node = json::object();  // create missing sections on the way down
      if (!node->is_object()) {
        override_fail(o, path,
                      fmt::format("is {} in the file, not an object, so \"{}\" cannot be set in it",
                                  brief(*node), seg));
      }
      path = join_path(path, seg);
      node = &(*node)[seg];
    } else {
      if (!node->is_array()) {
        override_fail(
            o, path,
            node->is_null()
                ? fmt::format("is not in the file, so it has no element {}; set it whole instead, "
                              "e.g. --set {}=[...]",
                              seg, path)
                : fmt::format("is {} in the file, not an array, so it has no element {}", brief(*node), seg));
      }
      size_t index = std::stoull(seg);
      if (index >= node->size()) {
        override_fail(o, path + "[" + seg + "]",
                      node->empty()
                          ? fmt::format("no such element: {} is empty", path)
                          : fmt::format("no such element: {} has {} element{}; use an index from 0 to {}",
                                        path, node->size(), node->size() == 1 ? "" : "s", node->size() - 1));
      }
      path += "[" + seg + "]";
      node = &(*node)[index];
    }
  }
  *node = std::move(value);
}

}  // namespace detail

}  // namespace haze::reflection
