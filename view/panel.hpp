// The parameter panel, generated from the scene's reflect() declarations (merian's idea: properties
// declared once drive the file and the UI): every camera, media, surface, haze, light, render, denoise and
// guiding key gets a widget from its type, with its range as the widget's limits, its choices as a combo
// box and its help as the tooltip. An edit is checked as a scene file is (reflect's reader and validate())
// before it reaches the renderer; a bad one is shown as the reader's one-line error and not applied.
#pragma once

#include <string>
#include <vector>

#include "scene/scene.hpp"

namespace haze::view {

struct PanelEdit {
  bool changed = false;
  bool camera_only = false;        // only camera.* keys changed
  std::vector<std::string> paths;  // the dotted paths edited this frame
};

// Draws the widgets of `s` (ImGui, inside the current window) and edits `s` in place. Keys that make no
// sense live (animation, render.frames, render.outputs) are left out; `drawn` receives every path drawn.
PanelEdit draw_parameters(scene::Scene& s, std::vector<std::string>* drawn = nullptr);

// `edited` checked as a scene file: through JSON and reflect's reader (ranges, choices, validate()).
// Returns the checked scene, or throws the reader's one-line error.
scene::Scene check_edit(const scene::Scene& edited);

}  // namespace haze::view
