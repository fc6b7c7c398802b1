#include "view/script.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace haze::view {

namespace fs = std::filesystem;

void validate(ScriptEntry& e, const reflection::Where& w) {
  if (e.frame < 0) w.fail("frame", "is required: the frame at whose start the entry applies");
  if (e.camera && !e.camera->is_object())
    w.fail("camera", "must be an object such as {\"position\": [0, 1, 5], \"target\": [0, 1, 0]}");
  if (e.set && !e.set->is_object())
    w.fail("set", "must be an object of dotted scene paths, such as {\"render.exposure\": 1}");
  if (!e.ui.is_null() && !e.ui.is_boolean())
    w.fail("ui", fmt::format("must be true or false, got {}", e.ui.dump()));
}

std::vector<ScriptStep> parse_script(const std::string& text, const std::string& origin,
                                     const scene::Scene& start, int frames, const LayerNames& layers) {
  const nlohmann::json j = reflection::parse_json(text, origin);
  const reflection::ReadContext ctx{origin, {}};
  if (!j.is_array())
    ctx.fail("", "a script is a list of entries such as [{\"frame\": 0, \"camera\": {...}}]");
  std::vector<ScriptStep> steps;
  for (size_t i = 0; i < j.size(); ++i) {
    ScriptStep st;
    const std::string at = fmt::format("[{}]", i);
    reflection::read_params(j[i], st.entry, ctx, at);
    st.where = fmt::format("{}: {}", origin, at);
    if (st.entry.frame >= frames)
      ctx.fail(at + ".frame",
               fmt::format("{} is never reached: the run has --frames {} (0 to {}); raise --frames",
                           st.entry.frame, frames, frames - 1));
    if (!st.entry.layer.empty() && std::find(layers.begin(), layers.end(), st.entry.layer) == layers.end()) {
      std::string names;
      for (const auto& l : layers) names += (names.empty() ? "" : ", ") + l;
      ctx.fail(at + ".layer", fmt::format("\"{}\" is not a layer; one of {}", st.entry.layer, names));
    }
    if (!st.entry.ui.is_null()) st.ui = st.entry.ui.get<bool>();
    steps.push_back(std::move(st));
  }
  std::stable_sort(steps.begin(), steps.end(),
                   [](const ScriptStep& a, const ScriptStep& b) { return a.entry.frame < b.entry.frame; });

  // The run, checked as scenes: each entry's keys applied (as --set) to the scene of the entries before it.
  nlohmann::json state = scene::to_json(start);
  for (ScriptStep& st : steps) {
    const ScriptEntry& e = st.entry;
    std::vector<std::string> assignments;
    bool camera_only = true;
    if (e.camera)
      for (const auto& [k, v] : e.camera->items())
        assignments.push_back(fmt::format("camera.{}={}", k, v.dump()));
    if (e.set)
      for (const auto& [k, v] : e.set->items()) {
        assignments.push_back(fmt::format("{}={}", k, v.dump()));
        camera_only = camera_only && k.rfind("camera.", 0) == 0;
      }
    st.scene_changed = !assignments.empty();
    st.camera_only = st.scene_changed && camera_only;
    // Messages name the entry: "FILE: [i]: render.spp: must be ...".
    const std::string where = st.where;
    for (const auto& a : assignments) scene::apply_override(state, a, where);
    st.scene = scene::from_json(state, where, start.base_dir);
    st.scene.path = start.path;
  }
  return steps;
}

std::vector<ScriptStep> load_script(const std::string& path, const scene::Scene& start, int frames,
                                    const LayerNames& layers) {
  std::error_code ec;
  if (fs::is_directory(path, ec))
    throw reflection::Error(
        fmt::format("cannot open script {}: it is a directory; pass the .json file", path));
  std::ifstream in(path, std::ios::binary);
  if (!in) throw reflection::Error(fmt::format("cannot open script {}: {}", path, std::strerror(errno)));
  std::stringstream buffer;
  buffer << in.rdbuf();
  return parse_script(buffer.str(), path, start, frames, layers);
}

}  // namespace haze::view
