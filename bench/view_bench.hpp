// The viewer in `haze bench --only view`: its frame wall time against the GPU time of the frame's passes
// (trace, resolve, denoisers, tonemap, the layer display, the copy into the window, the UI), over seeds.
// A ratio near 1 means the frame loop keeps the device busy: host work, presentation and waits hide behind
// the frames in flight. It needs an X display; without one it is skipped with a note.
#pragma once

#include <nlohmann/json.hpp>

#include "gpu/gpu.hpp"
#include "scene/scene.hpp"

namespace haze::bench {

struct ViewBenchOptions {
  int seeds = 3;
  int warmup = 6;   // frames left out (pipelines' first use, the window appearing)
  int frames = 24;  // frames measured per seed
  int spp = 1;      // samples per frame
};

nlohmann::json bench_view(const gpu::ContextOptions& co, const scene::Scene& s, const ViewBenchOptions& o);
void print_view(const nlohmann::json& j);

}  // namespace haze::bench
