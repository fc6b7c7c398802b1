#include "scene/scene.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>
#include <sstream>

#include "scene/animation.hpp"

namespace haze::scene {

// The reflection machinery (reflect/params.hpp) drives reading, writing and overriding scenes.
using namespace reflection;

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

std::string vec_text(const glm::vec3& v) {
  return fmt::format("[{}, {}, {}]", v.x, v.y, v.z);
}

// Normalises a direction in place; zero, tiny or non-finite lengths are an error.
void normalize_direction(glm::vec3& d, const Where& w, std::string_view key, std::string_view meaning) {
  float len = glm::length(d);
  if (!(len > 1e-12f) || !std::isfinite(len)) {
    w.fail(key, fmt::format("must be a nonzero vector ({}), got {}", meaning, vec_text(d)));
  }
  d /= len;
}

}  // namespace

glm::mat4 Transform::matrix() const {
  glm::mat4 m = glm::translate(glm::mat4(1.f), translate);
  m = glm::rotate(m, glm::radians(rotate.z), glm::vec3(0, 0, 1));
  m = glm::rotate(m, glm::radians(rotate.y), glm::vec3(0, 1, 0));
  m = glm::rotate(m, glm::radians(rotate.x), glm::vec3(1, 0, 0));
  return glm::scale(m, scale);
}

bool RenderSettings::wants(std::string_view output) const {
  return std::find(outputs.begin(), outputs.end(), output) != outputs.end();
}

void validate(Camera& c, const Where& w) {
  glm::vec3 forward = c.target - c.position;
  if (!(glm::length(forward) > 1e-6f)) {
    w.fail("target",
           fmt::format("equals {} ({}); move the target or the camera so that it has a view direction",
                       w.path("position"), vec_text(c.position)));
  }
  if (!(glm::length(c.up) > 1e-12f)) w.fail("up", "must be a nonzero vector, got " + vec_text(c.up));
  if (glm::length(glm::cross(glm::normalize(forward), glm::normalize(c.up))) < 1e-4f) {
    w.fail("up",
           fmt::format("{} is parallel to the view direction (target - position); choose another up vector",
                       vec_text(c.up)));
  }
}

// bounds_min < bounds_max in every component (NaN fails).
void check_box(glm::vec3 lo, glm::vec3 hi, const Where& w) {
  if (!glm::all(glm::lessThan(lo, hi)))
    w.fail("bounds_max", fmt::format("must be greater than bounds_min in every component, got {} and {}",
                                     vec_text(lo), vec_text(hi)));
}

void validate(Transform& t, const Where& w) {
  if (t.scale.x == 0.f || t.scale.y == 0.f || t.scale.z == 0.f) {
    w.fail("scale",
           "components must be nonzero (a zero scale flattens the volume), got " + vec_text(t.scale));
  }
}

void validate(Emission& e, const Where& w) {
  if (e.mode != "none" && e.grid.empty()) w.fail("grid", "must name a grid when mode is \"" + e.mode + "\"");
}

void validate(Surface& m, const Where& w) {
  if (!m.file.empty() && m.mesh)
    w.fail("mesh", "cannot be used together with \"file\"; keep exactly one of the two");
  if (m.file.empty() && !m.mesh)
    w.fail("", "needs a \"file\" (an .obj path) or a \"mesh\" spec; add one of the two");
  if (m.mesh && (!m.mesh->is_object() || !m.mesh->contains("kind") || !(*m.mesh)["kind"].is_string()))
    w.fail("mesh",
           "expected an object with a string \"kind\", like {\"kind\": \"box\"}, got " + m.mesh->dump());
}

// An all-zero multiplier would leave a medium that is nothing in every channel: say so instead.
static void check_sigma_t_color(const glm::vec3& c, float sigma_t, const Where& w, const char* scale_key) {
  if (sigma_t > 0.f && c.x == 0.f && c.y == 0.f && c.z == 0.f)
    w.fail("sigma_t_color", fmt::format("is [0, 0, 0], an empty medium; give some channel a multiplier > 0, "
                                        "or set {} to 0",
                                        scale_key));
}

void validate(Medium& m, const Where& w) {
  if (!m.file.empty() && m.procedural) {
    w.fail("procedural", "cannot be used together with \"file\"; keep exactly one of the two");
  }
  if (m.file.empty() && !m.procedural) {
    w.fail("", "needs a \"file\" (a .vdb path) or a \"procedural\" spec; add one of the two");
  }
  if (m.procedural) {
    const json& p = *m.procedural;
    if (!p.is_object())
      w.fail("procedural", "expected an object like {\"kind\": \"cloud\"}, got " + p.dump());
    auto kind = p.find("kind");
    if (kind == p.end() || !kind->is_string()) {
      w.fail("procedural.kind", "missing; set it to one of \"box\", \"sphere\", \"cloud\", \"height_fog\"");
    }
  }
  if (m.grid.empty()) w.fail("grid", "must name a float grid, e.g. \"density\"");
  check_box(m.bounds_min, m.bounds_max, w);
  check_sigma_t_color(m.sigma_t_color, m.density_scale, w, "density_scale");
  if (m.procedural && m.velocity)
    w.fail("velocity",
           "a procedural medium has no velocity grid; remove the key or use a .vdb file that has one");
  size_t runs = 0;
  for (size_t i = 0; i < m.file.size(); ++i) runs += m.file[i] == '#' && (i == 0 || m.file[i - 1] != '#');
  if (runs > 1) {
    w.fail("file", fmt::format("\"{}\" has {} runs of '#'; a sequence has one, the frame number, as in "
                               "smoke_####.vdb",
                               m.file, runs));
  }
}

void validate(Velocity& v, const Where& w) {
  if (v.grid.empty()) w.fail("grid", "must name a velocity grid, e.g. \"vel\"");
}

void validate(Haze& h, const Where& w) {
  if (h.bounded) check_box(h.bounds_min, h.bounds_max, w);
  check_sigma_t_color(h.sigma_t_color, h.sigma_t, w, "sigma_t");
}

void validate(Sun& s, const Where& w) {
  normalize_direction(s.direction, w, "direction", "towards the sun");
}

void validate(SpotLight& s, const Where& w) {
  normalize_direction(s.direction, w, "direction", "the axis of the cone");
  if (s.falloff_angle > s.cone_angle) {
    w.fail("falloff_angle", fmt::format("must be <= cone_angle ({}), got {}", s.cone_angle, s.falloff_angle));
  }
}

void validate(RenderSettings& r, const Where& w) {
  for (size_t i = 0; i < r.outputs.size(); ++i) {
    if (std::find(r.outputs.begin(), r.outputs.begin() + i, r.outputs[i]) != r.outputs.begin() + i) {
      w.fail(fmt::format("outputs[{}]", i), "\"" + r.outputs[i] + "\" is listed twice; list it once");
    }
  }
  std::pair<int, int> range;
  std::string error;
  if (!r.frames.empty() && !detail::parse_frame_range(r.frames, range, error)) w.fail("frames", error);
}

void validate(Key& k, const Where& w) {
  if (k.frame < 0) w.fail("frame", "missing; give the key's frame number, e.g. \"frame\": 0");
  if (k.value.is_null()) {
    w.fail("value", "missing; give the value at this frame, a number or [x, y, z] like the animated path");
  }
}

void validate(Track& t, const Where& w) {
  if (t.path.empty()) w.fail("path", "missing; name the animated value, e.g. \"camera.position\"");
  if (t.keys.empty()) w.fail("keys", "is empty; give at least one key {\"frame\": F, \"value\": V}");
  for (size_t k = 1; k < t.keys.size(); ++k) {
    if (t.keys[k].frame <= t.keys[k - 1].frame) {
      w.fail(
          fmt::format("keys[{}].frame", k),
          fmt::format("must be greater than keys[{}].frame ({}), got {}; list keys in frame order, one per "
                      "frame",
                      k - 1, t.keys[k - 1].frame, t.keys[k].frame));
    }
  }
}

namespace {

Scene read_scene(const json& j, const ReadContext& ctx, const std::string& base_dir) {
  Scene s;
  read_params(j, s, ctx);
  // A procedural medium has one grid, its density: a key naming another grid would be ignored, so only
  // "density" is accepted, and the medium says "density" for both.
  for (size_t i = 0; i < s.media.size(); ++i) {
    Medium& m = s.media[i];
    if (!m.procedural) continue;
    const json& mj = j.at("media").at(i);
    const bool emission_grid = mj.contains("emission") && mj["emission"].is_object() &&
                               mj["emission"].contains("grid") && !mj["emission"]["grid"].is_null();
    if (m.grid != "density")
      ctx.fail(fmt::format("media[{}].grid", i),
               fmt::format("\"{}\": a procedural medium has one grid, \"density\"; remove the key (or use a "
                           ".vdb file)",
                           m.grid));
    if (emission_grid && m.emission.grid != "density")
      ctx.fail(fmt::format("media[{}].emission.grid", i),
               fmt::format("\"{}\": a procedural medium's emission is driven by its density; remove the key "
                           "(or use a .vdb file that has that grid)",
                           m.emission.grid));
    m.emission.grid = "density";
  }
  s.path = ctx.origin;
  s.base_dir = base_dir;
  for (auto& m : s.surfaces) {
    for (std::string* f : {&m.file, &m.albedo_texture})
      if (!f->empty() && !base_dir.empty() && fs::path(*f).is_relative())
        *f = (fs::path(base_dir) / *f).lexically_normal().string();
  }
  for (auto& m : s.media) {
    if (!m.file.empty() && !base_dir.empty() && fs::path(m.file).is_relative()) {
      m.file = (fs::path(base_dir) / m.file).lexically_normal().string();
    }
  }
  if (auto& env = s.lights.environment; env && !env->file.empty()) {
    // A map's radiance is scaled by intensity alone: a tint would be a second meaning of color.
    if (env->color != glm::vec3(0))
      ctx.fail("lights.environment.color",
               fmt::format("[{}, {}, {}] together with lights.environment.file: the map gives the radiance "
                           "(scaled by intensity); remove color, or remove file for a constant environment",
                           env->color.x, env->color.y, env->color.z));
    if (!base_dir.empty() && fs::path(env->file).is_relative())
      env->file = (fs::path(base_dir) / env->file).lexically_normal().string();
  }
  detail::check_animation(s, ctx);
  return s;
}

}  // namespace

Scene from_json(const json& j, const std::string& origin, const std::string& base_dir) {
  ReadContext ctx{origin.empty() ? "<memory>" : origin, {}};
  Scene s = read_scene(j, ctx, base_dir);
  s.path = origin;
  return s;
}

json to_json(const Scene& s) {
  return write_params(s);
}

void apply_override(json& j, const std::string& assignment, const std::string& origin) {
  apply_override_to<Scene>(j, assignment, origin);
}

std::vector<ParamInfo> describe() {
  return describe_params<Scene>();
}

Scene load(const std::string& path, const std::vector<std::string>& overrides) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    throw Error(fmt::format("cannot open scene file {}: it is a directory; pass the .json file", path));
  }
  if (fs::exists(path, ec) && !fs::is_regular_file(path, ec))
    throw Error(
        fmt::format("cannot open scene file {}: not a regular file (a device, pipe or socket); pass the "
                    ".json file",
                    path));
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(fmt::format("cannot open scene file {}: {}", path, std::strerror(errno)));
  std::stringstream buffer;
  buffer << in.rdbuf();
  std::string text = buffer.str();

  json j = reflection::parse_json(text, path);

  ReadContext ctx{path, {}};
  for (const auto& o : overrides) ctx.overrides.emplace_back(apply_override_to<Scene>(j, o, path), o);

  std::string base_dir = fs::absolute(fs::path(path)).parent_path().lexically_normal().string();
  Scene s = read_scene(j, ctx, base_dir);
  s.path = path;
  // Files named by the scene must exist (a sequence's frames are checked below, per frame).
  // `list`[i].`field` as the file (or an override) wrote it: the hint about relative paths is for those only.
  auto written = [&](const char* list, size_t i, const char* field) {
    const nlohmann::json* v = j.contains(list) && j[list].is_array() && i < j[list].size() &&
                                      j[list][i].is_object() && j[list][i].contains(field)
                                  ? &j[list][i][field]
                                  : nullptr;
    return v && v->is_string() ? v->get<std::string>() : std::string();
  };
  auto require_file = [&](const std::string& key, const std::string& f, const std::string& as_written) {
    if (f.empty() || fs::is_regular_file(f, ec)) return;
    if (fs::exists(f, ec))
      ctx.fail(key, fmt::format("{} is {}, not a regular file; name a file", f,
                                fs::is_directory(f, ec) ? "a directory" : "a device, pipe or socket"));
    if (fs::path(as_written).is_absolute()) ctx.fail(key, fmt::format("no such file: {}; check the path", f));
    ctx.fail(key, fmt::format("no such file: {} (relative paths start at the scene file's folder {})", f,
                              base_dir));
  };
  for (size_t i = 0; i < s.media.size(); ++i)
    if (!is_sequence(s.media[i].file))
      require_file(fmt::format("media[{}].file", i), s.media[i].file, written("media", i, "file"));
  if (const auto& env = s.lights.environment; env) {
    const nlohmann::json* v =
        j.contains("lights") && j["lights"].is_object() && j["lights"].contains("environment") &&
                j["lights"]["environment"].is_object() && j["lights"]["environment"].contains("file")
            ? &j["lights"]["environment"]["file"]
            : nullptr;
    require_file("lights.environment.file", env->file, v && v->is_string() ? v->get<std::string>() : "");
  }
  for (size_t i = 0; i < s.surfaces.size(); ++i) {
    require_file(fmt::format("surfaces[{}].file", i), s.surfaces[i].file, written("surfaces", i, "file"));
    require_file(fmt::format("surfaces[{}].albedo_texture", i), s.surfaces[i].albedo_texture,
                 written("surfaces", i, "albedo_texture"));
  }
  auto [first, last] = frame_range(s);
  detail::check_frame_files(s, first, last, ctx);
  return s;
}

}  // namespace haze::scene
