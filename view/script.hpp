// Scripted viewer runs (`haze view SCENE --script FILE --frames N`): a JSON list of entries, each applied
// at the start of its frame,
//
//   [{"frame": 0, "ui": false},
//    {"frame": 4, "camera": {"position": [1, 2, 3], "target": [0, 1, 0]}, "screenshot": "moved.png"},
//    {"frame": 8, "set": {"guiding.enabled": true}, "layer": "volume"},
//    {"frame": 9, "save_scene": "state.json", "save_image": "state/"}]
//
// The file is read as scene files are (the same one-line errors naming the file and the key), and the
// whole run is checked before the window opens: each entry's camera and settings are applied to the scene
// in frame order and the result read as a scene, so a bad value fails at once, naming the entry.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "reflect/params.hpp"
#include "scene/scene.hpp"

namespace haze::view {

// One entry as the file has it.
struct ScriptEntry {
  int frame = -1;                        // required
  std::optional<nlohmann::json> camera;  // any of the scene's camera keys: position, target, up, fov_y
  std::optional<nlohmann::json> set;     // {"dotted.path": value}, as --set
  std::string layer;                     // "" keeps the layer shown
  nlohmann::json ui;                     // null keeps it; true shows the panel, false hides it
  std::string screenshot;                // PNG of the window after this frame is presented
  std::string save_scene;                // the scene as it is at this frame
  std::string save_image;                // a folder: this frame's EXR layers, PNG and stats.json
};

template <class V>
void reflect(V& v, ScriptEntry& e) {
  using reflection::Range;
  v.field("frame", e.frame, Range{0, 1e9}, "the frame at whose start the entry applies (required)");
  v.field("camera", e.camera, "camera keys to set: position, target, up, fov_y");
  v.field("set", e.set, "scene values by dotted path, {\"render.exposure\": 1}");
  v.field("layer", e.layer, "the layer to show (the viewer's layer names)");
  v.field("ui", e.ui, "true shows the panel, false hides it");
  v.field("screenshot", e.screenshot, "PNG of the window (UI included when shown) after this frame");
  v.field("save_scene", e.save_scene, "write the scene as it is at this frame");
  v.field("save_image", e.save_image, "folder: write this frame's EXR layers, PNG and stats.json");
}
void validate(ScriptEntry& e, const reflection::Where& w);

// An entry with the scene it leads to.
struct ScriptStep {
  ScriptEntry entry;
  std::string where;         // "FILE: [i]" for messages
  scene::Scene scene;        // the scene from this frame on
  bool camera_only = false;  // only camera keys changed (the renderer's fast path)
  bool scene_changed = false;
  std::optional<bool> ui;
};

// The layer names a script may show (view/layers.hpp).
using LayerNames = std::vector<std::string>;

// Reads and checks a script against `start` (the scene the viewer opens with) and the run's `frames`.
// Entries are sorted by frame (stable). Throws reflection::Error "<file>: [i].<key>: ...".
std::vector<ScriptStep> load_script(const std::string& path, const scene::Scene& start, int frames,
                                    const LayerNames& layers);
// The same from JSON text (tests); `origin` names it in messages.
std::vector<ScriptStep> parse_script(const std::string& text, const std::string& origin,
                                     const scene::Scene& start, int frames, const LayerNames& layers);

}  // namespace haze::view
