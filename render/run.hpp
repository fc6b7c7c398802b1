// Rendering a scene's frames with one Renderer: the loop `haze render`, `haze reference` and sweeps share.
#pragma once

#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "render/renderer.hpp"

namespace haze::render {

struct FrameLoop {
  std::function<void(int frame, const Image&)> on_frame;  // after each frame's resolve
  std::function<void(int done, int total)> progress;      // after each sample
  std::function<void(const std::string&)> on_note;        // each distinct note of the renderer, once
  std::function<void(int frame, int first, int last)> on_frame_start;
};

struct RunSummary {
  nlohmann::json per_frame = nlohmann::json::array();  // {frame, setup_s, render_s, gpu_ms, trace_gpu_ms}
  std::vector<std::string> notes;
  double setup_s = 0, render_s = 0;
  double gpu_ms = 0;       // every pass's GPU time over all frames
  FrameCounters counters;  // Image::counters summed over all frames
  nlohmann::json stats;    // Renderer::stats() after the last frame: passes, memory, features
};

// Renders frames [first, last] of `s` (each through scene_at_frame, with the previous frame for motion).
// `r` is reused when it holds a Renderer (restarted: its pipelines are kept, nothing else), else made.
RunSummary render_frames(gpu::Context& ctx, const scene::Scene& s, int first, int last, const FrameLoop& loop,
                         std::unique_ptr<Renderer>& r);

// Points `r` at frame f of `s` (with the previous frame for motion) and returns that frame's scene: makes the
// Renderer, restarts it for a new run (`fresh`: pipelines kept, nothing else), or moves it to the next frame.
scene::Scene use_frame(gpu::Context& ctx, std::unique_ptr<Renderer>& r, const scene::Scene& s, int f,
                       bool fresh);

// Checks what the scene reader leaves to the parts, before a device starts: procedural volume and mesh
// specs, and that each .vdb has the grids the scene names. Throws Error "<scene file>: <key>: ...".
void check_part_specs(const scene::Scene& s);

// The figures a run ends with (`haze render`, `haze stats`): {samples, frames, render_s, gpu_ms_per_frame,
// passes: {name: GPU ms per frame}, memory: the ledger's {total, peak, per_category}}.
nlohmann::json summary_of_stats(const nlohmann::json& stats);  // of a stats.json of `haze render`
// Three lines: samples and time; the three most expensive passes with their share; memory per category
// (largest first) with the total and peak.
std::string format_summary(const nlohmann::json& summary);

// Sum of every pass's recorded GPU times.
double total_gpu_ms(const Renderer& r);

}  // namespace haze::render
