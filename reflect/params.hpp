// Parameter reflection: each parameter struct lists its fields once, in a `reflect` function found by
// argument-dependent lookup,
//
//   template <class V> void reflect(V& v, RenderSettings& s) {
//     v.field("width", s.width, Range{1, 16384}, "image width in pixels");
//     v.field("tonemap", s.tonemap, Choices{"aces", "reinhard", "clamp"}, "tone curve of the PNG preview");
//   }
//
// and that one list drives JSON reading (type, range and choice checks, unknown keys), JSON writing (the
// effective settings), `describe` (docs, --help-params) and `--set dotted.path=value` overrides, so the
// four can never disagree. Cross-field checks go in an optional `void validate(T&, const Where&)`, also
// found by argument-dependent lookup; declare it next to the struct so every reader sees it.
//
// Field types: bool, int, uint32_t, float, double, std::string (optionally with Choices), glm::vec3
// (JSON [x, y, z]), std::vector<std::string>, nlohmann::json / std::optional<nlohmann::json> (free-form,
// checked by whoever reads it), reflected structs, std::vector<struct>, std::optional<struct>.
#pragma once

#include <cstdint>
#include <glm/vec3.hpp>
#include <initializer_list>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

namespace haze::reflection {

// One line: "<file>: <json.path>: <what is wrong; what to do>".
struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Closed interval by default; either end may be open or infinite.
struct Range {
  double lo = -std::numeric_limits<double>::infinity();
  double hi = std::numeric_limits<double>::infinity();
  bool lo_open = false;
  bool hi_open = false;

  constexpr Range() = default;
  constexpr Range(double lo_, double hi_, bool lo_open_ = false, bool hi_open_ = false)
      : lo(lo_), hi(hi_), lo_open(lo_open_), hi_open(hi_open_) {}
  static constexpr Range at_least(double lo) { return {lo, std::numeric_limits<double>::infinity()}; }
  static constexpr Range above(double lo) { return {lo, std::numeric_limits<double>::infinity(), true}; }
  static constexpr Range open(double lo, double hi) { return {lo, hi, true, true}; }

  bool contains(double x) const;
  std::string text() const;  // ">= 0", "in [1, 16384]", "in (0, 180)"
};

// The allowed values of a string field (or of each element of a string list).
struct Choices {
  std::vector<std::string> names;
  Choices(std::initializer_list<std::string_view> n) : names(n.begin(), n.end()) {}
  bool contains(std::string_view s) const;
  std::string text() const;  // one of "aces", "reinhard", "clamp"
};

struct Constraint {
  std::optional<Range> range;
  std::optional<Choices> choices;
  std::string text() const;  // "" when unconstrained
};

// What `describe` reports about one dotted path. Paths into lists use "[]": "media[].albedo".
struct ParamInfo {
  std::string path;
  std::string type;           // "integer", "number", "[x, y, z]", "object", "list of objects", ...
  std::string default_value;  // JSON text; "" for objects and "absent" for optional objects
  std::string constraint;     // Constraint::text()
  std::string help;
};
// The JSON path of the first key that appears twice in one object of `text` ("render.spp",
// "media[1].grid"); "" when there is none or when `text` is not valid JSON (its parser says that).
// nlohmann::json keeps the last of two equal keys without a word.
std::string duplicate_key(const std::string& text, bool ignore_comments = true);

// Parses a hand-written JSON file's text (comments allowed) as scene files are read: malformed JSON is an
// Error "<origin>: line L, column C: malformed JSON: ...; fix the syntax there", a key repeated in one
// object an Error naming its path.
nlohmann::json parse_json(const std::string& text, const std::string& origin);

// A plain-text table of `describe` output, for `haze render --help-params`.
std::string format_params(const std::vector<ParamInfo>& params);

// Where a value is being read; builds the error messages.
struct ReadContext {
  std::string origin;  // file name, or a label such as "<memory>"
  // (JSON path, assignment) of each --set applied, so a bad value names the override it came from.
  std::vector<std::pair<std::string, std::string>> overrides;

  [[noreturn]] void fail(std::string_view path, std::string_view what) const;
};

// "a.b" + "c" -> "a.b.c"; "a" + "[2]" -> "a[2]"; either side may be empty.
std::string join_path(std::string_view path, std::string_view key);

// Passed to validate(): errors about a key of the object being validated.
class Where {
 public:
  Where(const ReadContext& ctx, std::string path) : ctx_(ctx), path_(std::move(path)) {}
  // key "" names the object itself.
  [[noreturn]] void fail(std::string_view key, std::string_view what) const {
    ctx_.fail(join_path(path_, key), what);
  }
  std::string path(std::string_view key = {}) const { return join_path(path_, key); }
  const std::string& origin() const { return ctx_.origin; }

 private:
  const ReadContext& ctx_;
  std::string path_;
};

// CRTP base: the three spellings of `field` forward to Derived::visit(name, value, constraint, help).
template <class Derived>
class Visitor {
 public:
  template <class T>
  void field(std::string_view name, T& value, std::string_view help) {
    self().visit(name, value, Constraint{}, help);
  }
  template <class T>
  void field(std::string_view name, T& value, const Range& range, std::string_view help) {
    self().visit(name, value, Constraint{range, std::nullopt}, help);
  }
  template <class T>
  void field(std::string_view name, T& value, const Choices& choices, std::string_view help) {
    self().visit(name, value, Constraint{std::nullopt, choices}, help);
  }

 private:
  Derived& self() { return static_cast<Derived&>(*this); }
};

namespace detail {

template <class T>
struct is_vector : std::false_type {};
template <class T, class A>
struct is_vector<std::vector<T, A>> : std::true_type {};
template <class T>
struct is_optional : std::false_type {};
template <class T>
struct is_optional<std::optional<T>> : std::true_type {};

template <class T>
inline constexpr bool always_false = false;

class KeyList : public Visitor<KeyList> {
 public:
  std::vector<std::string> names;
  template <class T>
  void visit(std::string_view name, T&, const Constraint&, std::string_view) {
    names.emplace_back(name);
  }
};

}  // namespace detail

template <class T>
concept Reflectable = std::is_class_v<T> && requires(detail::KeyList& k, T& t) {
  reflect(k, t);
};
// Conjunctions in concepts short-circuit, so these are safe to test on any T.
template <class T>
concept ReflectableVector = detail::is_vector<T>::value && Reflectable<typename T::value_type>;
template <class T>
concept ReflectableOptional = detail::is_optional<T>::value && Reflectable<typename T::value_type>;
template <class T>
concept Validated = requires(T& t, const Where& w) {
  validate(t, w);
};

namespace detail {

using json = nlohmann::json;

// Leaf readers (params.cpp): each checks the JSON type, finiteness and the constraint.
bool read_bool(const json& j, const ReadContext& ctx, const std::string& path);
double read_number(const json& j, const Constraint& c, bool as_float, const ReadContext& ctx,
                   const std::string& path);
long long read_integer(const json& j, const Constraint& c, long long lo, long long hi, const ReadContext& ctx,
                       const std::string& path);
std::string read_string(const json& j, const Constraint& c, const ReadContext& ctx, const std::string& path);
glm::vec3 read_vec3(const json& j, const Constraint& c, const ReadContext& ctx, const std::string& path);
std::vector<std::string> read_string_list(const json& j, const Constraint& c, const ReadContext& ctx,
                                          const std::string& path);
void expect_object(const json& j, const ReadContext& ctx, const std::string& path);
void expect_array(const json& j, const ReadContext& ctx, const std::string& path, std::string_view what);
void check_keys(const json& j, const std::vector<std::string>& names, const ReadContext& ctx,
                const std::string& path);
// "unknown key (did you mean "spp"?)" or "unknown key; expected one of: ..."
std::string unknown_key_message(std::string_view key, const std::vector<std::string>& names);

json write_float(float f);  // shortest text that reads back as the same float: 0.9f -> 0.9
json write_vec3(const glm::vec3& v);

template <class T>
void read_struct(const json& j, T& v, const ReadContext& ctx, const std::string& path);

template <class T>
void read_value(const json& j, T& v, const Constraint& c, const ReadContext& ctx, const std::string& path) {
  if constexpr (std::is_same_v<T, bool>) {
    v = read_bool(j, ctx, path);
  } else if constexpr (std::is_same_v<T, int> || std::is_same_v<T, uint32_t>) {
    v = static_cast<T>(
        read_integer(j, c, std::numeric_limits<T>::min(), std::numeric_limits<T>::max(), ctx, path));
  } else if constexpr (std::is_same_v<T, float> || std::is_same_v<T, double>) {
    v = static_cast<T>(read_number(j, c, std::is_same_v<T, float>, ctx, path));
  } else if constexpr (std::is_same_v<T, std::string>) {
    v = read_string(j, c, ctx, path);
  } else if constexpr (std::is_same_v<T, glm::vec3>) {
    v = read_vec3(j, c, ctx, path);
  } else if constexpr (std::is_same_v<T, std::vector<std::string>>) {
    v = read_string_list(j, c, ctx, path);
  } else if constexpr (std::is_same_v<T, json>) {
    v = j;
  } else if constexpr (std::is_same_v<T, std::optional<json>>) {
    if (j.is_null())
      v.reset();
    else
      v = j;
  } else if constexpr (Reflectable<T>) {
    read_struct(j, v, ctx, path);
  } else if constexpr (ReflectableVector<T>) {
    expect_array(j, ctx, path, "objects");
    T out;
    out.reserve(j.size());
    for (size_t i = 0; i < j.size(); ++i) {
      read_struct(j[i], out.emplace_back(), ctx, path + "[" + std::to_string(i) + "]");
    }
    v = std::move(out);
  } else if constexpr (ReflectableOptional<T>) {
    // null switches an optional section off; a partial object fills in the rest from defaults.
    if (j.is_null()) {
      v.reset();
    } else {
      if (!v) v.emplace();
      read_struct(j, *v, ctx, path);
    }
  } else {
    static_assert(always_false<T>, "unsupported parameter type");
  }
}

class FromJson : public Visitor<FromJson> {
 public:
  FromJson(const json& obj, const ReadContext& ctx, const std::string& path)
      : obj_(obj), ctx_(ctx), path_(path) {}
  template <class T>
  void visit(std::string_view name, T& value, const Constraint& c, std::string_view) {
    auto it = obj_.find(name);
    if (it != obj_.end()) read_value(*it, value, c, ctx_, join_path(path_, name));
  }

 private:
  const json& obj_;
  const ReadContext& ctx_;
  const std::string& path_;
};

template <class T>
void read_struct(const json& j, T& v, const ReadContext& ctx, const std::string& path) {
  expect_object(j, ctx, path);
  // Unknown keys first: a typo is the likeliest cause of any later surprise.
  KeyList keys;
  reflect(keys, v);
  check_keys(j, keys.names, ctx, path);
  FromJson reader(j, ctx, path);
  reflect(reader, v);
  if constexpr (Validated<T>) validate(v, Where(ctx, path));
}

template <class T>
json write_value(const T& v);

class ToJson : public Visitor<ToJson> {
 public:
  explicit ToJson(json& out) : out_(out) {}
  template <class T>
  void visit(std::string_view name, T& value, const Constraint&, std::string_view) {
    if constexpr (is_optional<T>::value) {
      if (!value) return;  // absent optional sections stay absent
    }
    out_[std::string(name)] = write_value(value);
  }

 private:
  json& out_;
};

template <class T>
json write_value(const T& v) {
  if constexpr (std::is_same_v<T, float>) {
    return write_float(v);
  } else if constexpr (std::is_same_v<T, glm::vec3>) {
    return write_vec3(v);
  } else if constexpr (std::is_same_v<T, bool> || std::is_arithmetic_v<T> || std::is_same_v<T, std::string> ||
                       std::is_same_v<T, std::vector<std::string>> || std::is_same_v<T, json>) {
    return json(v);
  } else if constexpr (Reflectable<T>) {
    json out = json::object();
    ToJson writer(out);
    reflect(writer, const_cast<T&>(v));  // reflect takes T&; ToJson only reads
    return out;
  } else if constexpr (is_vector<T>::value) {
    json out = json::array();
    for (const auto& e : v) out.push_back(write_value(e));
    return out;
  } else if constexpr (is_optional<T>::value) {
    return v ? write_value(*v) : json();
  } else {
    static_assert(always_false<T>, "unsupported parameter type");
  }
}

template <class T>
std::string type_name() {
  if constexpr (std::is_same_v<T, bool>)
    return "bool";
  else if constexpr (std::is_same_v<T, int>)
    return "integer";
  else if constexpr (std::is_same_v<T, uint32_t>)
    return "unsigned integer";
  else if constexpr (std::is_floating_point_v<T>)
    return "number";
  else if constexpr (std::is_same_v<T, std::string>)
    return "string";
  else if constexpr (std::is_same_v<T, glm::vec3>)
    return "[x, y, z]";
  else if constexpr (std::is_same_v<T, std::vector<std::string>>)
    return "list of strings";
  else if constexpr (std::is_same_v<T, json>)
    return "JSON value";
  else if constexpr (std::is_same_v<T, std::optional<json>>)
    return "JSON object";
  else if constexpr (Reflectable<T>)
    return "object";
  else if constexpr (is_vector<T>::value)
    return "list of objects";
  else if constexpr (is_optional<T>::value)
    return "optional object";
  else
    static_assert(always_false<T>, "unsupported parameter type");
}

template <class T>
void describe_into(std::vector<ParamInfo>& out, const std::string& prefix);

class Describe : public Visitor<Describe> {
 public:
  Describe(std::vector<ParamInfo>& out, const std::string& prefix) : out_(out), prefix_(prefix) {}
  template <class T>
  void visit(std::string_view name, T& value, const Constraint& c, std::string_view help) {
    std::string path = join_path(prefix_, name);
    std::string def;
    if constexpr (is_optional<T>::value) {
      def = value ? write_value(value).dump() : "absent";
    } else if constexpr (!Reflectable<T>) {
      def = write_value(value).dump();
    }
    out_.push_back({path, type_name<T>(), def, c.text(), std::string(help)});
    if constexpr (Reflectable<T>) {
      // The member's own defaults: a parent may set them apart from T's (the volume denoiser's).
      T copy = value;
      Describe d(out_, path);
      reflect(d, copy);
    } else if constexpr (ReflectableVector<T>) {
      describe_into<typename T::value_type>(out_, path + "[]");
    } else if constexpr (ReflectableOptional<T>) {
      describe_into<typename T::value_type>(out_, path);
    }
  }

 private:
  std::vector<ParamInfo>& out_;
  const std::string& prefix_;
};

template <class T>
void describe_into(std::vector<ParamInfo>& out, const std::string& prefix) {
  T defaults{};
  Describe d(out, prefix);
  reflect(d, defaults);
}

// --set support: the schema walk (templates, below) turns "media.0.g" into steps and a target kind;
// set_override (params.cpp) then parses the value for that kind and writes it into the JSON.
enum class Target { Bool, Integer, Number, String, Vec3, StringList, Object, ObjectList, Json };
enum class Step { Key, Index, Free };  // Free: inside a free-form JSON value, decided by the data

struct Override {
  std::string assignment;         // the whole "path=value", for messages
  std::string origin;             // for messages
  std::vector<std::string> segs;  // "media", "0", "g"
  std::vector<Step> steps;        // one per segment
  std::string json_path;          // "media[0].g", grows while resolving
  Target target = Target::Object;
};

// Splits "a.b[2].c" (or "a.b.2.c") into "a", "b", "2", "c"; false if a part is empty.
// Splits "a.b[0].c" (or "a.b.0.c") into keys; "" on success, else what is wrong ("an empty part").
std::string split_path(std::string_view path, std::vector<std::string>& segs);
// Splits "a.b[2].c=v" into segments and value; throws on a malformed assignment.
Override parse_assignment(std::string_view assignment, std::string_view origin, std::string& value);
[[noreturn]] void override_fail(const Override& o, std::string_view path, std::string_view what);
long long parse_index(const Override& o, size_t pos, long long limit);  // limit < 0: no limit
void set_override(nlohmann::json& root, const Override& o, std::string_view value);

template <class T>
void resolve_value(Override& o, size_t pos);

class Resolver : public Visitor<Resolver> {
 public:
  Resolver(Override& o, size_t pos) : o_(o), pos_(pos) {}
  bool matched() const { return matched_; }
  template <class T>
  void visit(std::string_view name, T&, const Constraint&, std::string_view) {
    if (matched_ || name != o_.segs[pos_]) return;
    matched_ = true;
    o_.json_path = join_path(o_.json_path, name);
    o_.steps.push_back(Step::Key);
    resolve_value<T>(o_, pos_ + 1);
  }

 private:
  Override& o_;
  size_t pos_;
  bool matched_ = false;
};

template <class T>
void resolve_struct(Override& o, size_t pos) {
  T defaults{};
  Resolver r(o, pos);
  reflect(r, defaults);
  if (!r.matched()) {
    KeyList keys;
    reflect(keys, defaults);
    override_fail(o, join_path(o.json_path, o.segs[pos]), unknown_key_message(o.segs[pos], keys.names));
  }
}

template <class T>
void resolve_value(Override& o, size_t pos) {
  const bool at_end = pos == o.segs.size();
  auto no_members = [&](std::string_view kind, size_t at) {
    override_fail(o, o.json_path,
                  "has no member \"" + o.segs[at] + "\" (it is a single " + std::string(kind) + ")");
  };
  if constexpr (std::is_same_v<T, json> || std::is_same_v<T, std::optional<json>>) {
    o.target = Target::Json;
    for (size_t i = pos; i < o.segs.size(); ++i) o.steps.push_back(Step::Free);
    for (size_t i = pos; i < o.segs.size(); ++i) o.json_path = join_path(o.json_path, o.segs[i]);
  } else if constexpr (Reflectable<T>) {
    if (at_end)
      o.target = Target::Object;
    else
      resolve_struct<T>(o, pos);
  } else if constexpr (is_optional<T>::value) {
    resolve_value<typename T::value_type>(o, pos);
  } else if constexpr (std::is_same_v<T, glm::vec3> || is_vector<T>::value) {
    constexpr bool vec3 = std::is_same_v<T, glm::vec3>;
    if (at_end) {
      if constexpr (vec3)
        o.target = Target::Vec3;
      else if constexpr (std::is_same_v<T, std::vector<std::string>>)
        o.target = Target::StringList;
      else
        o.target = Target::ObjectList;
      return;
    }
    long long i = parse_index(o, pos, vec3 ? 3 : -1);
    // Appended piecewise: GCC 12 warns falsely (-Wrestrict) about "[" + std::to_string(i) + "]" here.
    o.json_path += '[';
    o.json_path += std::to_string(i);
    o.json_path += ']';
    o.steps.push_back(Step::Index);
    if constexpr (vec3) {
      if (pos + 1 != o.segs.size()) no_members("number", pos + 1);
      o.target = Target::Number;
    } else if constexpr (std::is_same_v<T, std::vector<std::string>>) {
      if (pos + 1 != o.segs.size()) no_members("string", pos + 1);
      o.target = Target::String;
    } else {
      resolve_value<typename T::value_type>(o, pos + 1);
    }
  } else {
    if (!at_end) no_members(type_name<T>(), pos);
    if constexpr (std::is_same_v<T, bool>)
      o.target = Target::Bool;
    else if constexpr (std::is_integral_v<T>)
      o.target = Target::Integer;
    else if constexpr (std::is_floating_point_v<T>)
      o.target = Target::Number;
    else if constexpr (std::is_same_v<T, std::string>)
      o.target = Target::String;
    else
      static_assert(always_false<T>, "unsupported parameter type");
  }
}

}  // namespace detail

// Reads `j` into `out` (fields absent from `j` keep their current values) and runs validate().
template <class T>
void read_params(const nlohmann::json& j, T& out, const ReadContext& ctx, const std::string& path = {}) {
  detail::read_struct(j, out, ctx, path);
}

template <class T>
nlohmann::json write_params(const T& v) {
  return detail::write_value(v);
}

// Every dotted path of T with its type, default, constraint and help, depth first in declaration order.
template <class T>
std::vector<ParamInfo> describe_params(const std::string& prefix = {}) {
  std::vector<ParamInfo> out;
  detail::describe_into<T>(out, prefix);
  return out;
}

// Applies "dotted.path=value" to `j`, a JSON document of schema T. The path must exist in the schema
// (array elements must also exist in `j`); missing objects on the way are created, so setting a key of
// an absent optional section switches that section on. Returns the JSON path it set ("media[0].g").
template <class T>
std::string apply_override_to(nlohmann::json& j, std::string_view assignment, std::string_view origin) {
  std::string value;
  detail::Override o = detail::parse_assignment(assignment, origin, value);
  detail::resolve_struct<T>(o, 0);
  detail::set_override(j, o, value);
  return o.json_path;
}

}  // namespace haze::reflection
