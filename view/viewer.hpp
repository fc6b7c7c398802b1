// `haze view`: a live window on a scene. Each frame traces more samples (progressive while nothing
// changes), resolves, runs both denoisers and the tonemap, shows the chosen layer and draws the UI on top;
// two frames are in flight and their GPU times arrive a frame late. A change that needs new shader
// permutations is compiled in the background while the old pipelines keep rendering the old state.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "gpu/context.hpp"
#include "scene/scene.hpp"

namespace haze::view {

struct ViewOptions {
  int spp = 1;             // samples added per frame
  int frames = 0;          // exit after this many frames (0: when the window closes)
  std::string script;      // view/script.hpp
  std::string screenshot;  // PNG of the last presented frame, written at exit
  std::string stats;       // JSON of the run: per-frame times, samples, compiles
  int scale = 0;           // image pixels per rendered pixel; 0: the largest that fits 960x720
  std::string layer = "final";
  bool ui = true;
};

// What a run measured (also written to ViewOptions::stats).
struct ViewRun {
  nlohmann::json stats;
  uint64_t validation_messages = 0;
};

// Opens the window and runs until it closes or `frames` are done. `s` is the scene to show (its
// animation, if any, at its first frame). Throws on bad input (a one-line error) before the window opens.
ViewRun run_view(const scene::Scene& s, const ViewOptions& o, const gpu::ContextOptions& co);

}  // namespace haze::view
