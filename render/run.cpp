#include "render/run.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>

#include "scene/animation.hpp"

namespace haze::render {

double total_gpu_ms(const Renderer& r) {
  double ms = 0;
  for (const auto& [name, st] : r.pass_stats())
    for (double t : st.ms) ms += t;
  return ms;
}

scene::Scene use_frame(gpu::Context& ctx, std::unique_ptr<Renderer>& r, const scene::Scene& s, int f,
                       bool fresh) {
  scene::Scene fs = scene::scene_at_frame(s, f);
  scene::Scene prev = scene::scene_at_frame(s, f - 1);  // for motion vectors
  if (!r)
    r = std::make_unique<Renderer>(ctx, fs, uint32_t(f), &prev);
  else if (fresh)
    r->restart(fs, uint32_t(f), &prev);
  else
    r->set_scene(fs, uint32_t(f), &prev);
  return fs;
}

RunSummary render_frames(gpu::Context& ctx, const scene::Scene& s, int first, int last, const FrameLoop& loop,
                         std::unique_ptr<Renderer>& r) {
  using clock = std::chrono::steady_clock;
  RunSummary out;
  for (int f = first; f <= last; ++f) {
    auto t0 = clock::now();
    scene::Scene fs = use_frame(ctx, r, s, f, f == first);
    for (const auto& n : r->notes())
      if (std::find(out.notes.begin(), out.notes.end(), n) == out.notes.end()) {
        if (loop.on_note) loop.on_note(n);
        out.notes.push_back(n);
      }
    auto t1 = clock::now();
    if (loop.on_frame_start) loop.on_frame_start(f, first, last);
    const double gpu_before = total_gpu_ms(*r);
    const auto& passes = r->pass_stats();
    size_t trace_before = passes.count("trace") ? passes.at("trace").ms.size() : 0;
    r->add_samples(fs.render.spp, loop.progress);
    Image img = r->resolve();
    auto t2 = clock::now();
    if (loop.on_frame) loop.on_frame(f, img);
    const auto& trace = r->pass_stats().at("trace").ms;
    double trace_ms = 0;
    for (size_t i = trace_before; i < trace.size(); ++i) trace_ms += trace[i];
    const double gpu_ms = total_gpu_ms(*r) - gpu_before;
    double fsetup = std::chrono::duration<double>(t1 - t0).count();
    double frender = std::chrono::duration<double>(t2 - t1).count();
    out.setup_s += fsetup;
    out.render_s += frender;
    out.gpu_ms += gpu_ms;
    out.per_frame.push_back({{"frame", f},
                             {"setup_s", fsetup},
                             {"render_s", frender},
                             {"gpu_ms", gpu_ms},
                             {"trace_gpu_ms", trace_ms},
                             {"non_finite", img.non_finite},
                             {"clamped_squares", img.clamped_squares}});
    out.non_finite += img.non_finite;
    out.clamped_squares += img.clamped_squares;
  }
  // What the estimator dropped or clamped, said once for the run (per frame in per_frame).
  auto say = [&](const std::string& n) {
    if (loop.on_note) loop.on_note(n);
    out.notes.push_back(n);
  };
  if (out.non_finite > 0)
    say(fmt::format("{} samples had a non-finite radiance and were dropped (each counted as a zero sample)",
                    out.non_finite));
  if (out.clamped_squares > 0)
    say(fmt::format(
        "{} samples had a squared radiance above {:g}, clamped there so that sums of squares stay "
        "finite; variance and surface_demod_m2 are lower bounds in those pixels",
        out.clamped_squares, double(glsl::SQUARE_MAX)));
  out.stats = r->stats();
  return out;
}

}  // namespace haze::render
