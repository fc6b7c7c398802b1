#include "render/run.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>

#include "render/output.hpp"
#include "scene/animation.hpp"
#include "surfaces/scene_geometry.hpp"
#include "vdb/vdb.h"

namespace haze::render {

void check_part_specs(const scene::Scene& s) {
  const std::string file = s.path.empty() ? "" : s.path + ": ";
  try {
    for (size_t i = 0; i < s.media.size(); ++i) {
      const scene::Medium& m = s.media[i];
      const std::string where = fmt::format("media[{}]", i);
      if (m.procedural) {
        vdb::procedural_from_json(*m.procedural, where + ".procedural");
      } else if (!m.file.empty() && !scene::is_sequence(m.file)) {
        vdb::check_grid_name(m.file, m.grid, where + ".grid");
        if (m.emission.mode != "none" && m.emission.grid != m.grid)
          vdb::check_grid_name(m.file, m.emission.grid, where + ".emission.grid");
        if (m.velocity) vdb::check_velocity_name(m.file, m.velocity->grid, where + ".velocity.grid");
      }
    }
    for (size_t i = 0; i < s.surfaces.size(); ++i)
      if (s.surfaces[i].mesh)
        surfaces::mesh_from_json(*s.surfaces[i].mesh, fmt::format("surfaces[{}].mesh", i));
  } catch (const std::exception& e) {
    throw Error(file + e.what());
  }
}

double total_gpu_ms(const Renderer& r) {
  double ms = 0;
  for (const auto& [name, st] : r.pass_stats_so_far())
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
  // Frames stream: a frame's samples and resolve are submitted without waiting, and its image reaches the
  // host (on_frame: writing its files) while the next frame renders. Per-frame GPU times are the passes
  // recorded since the previous frame's image arrived (each submission's times arrive with it, in order).
  double gpu_seen = 0;
  size_t trace_seen = 0;
  auto arrived = [&](int f, double setup_s, clock::time_point t1, Image img) {
    const auto t2 = clock::now();
    if (loop.on_frame) loop.on_frame(f, img);
    const double gpu_total = total_gpu_ms(*r);
    const auto& passes = r->pass_stats_so_far();
    const std::vector<double> none;
    const auto& trace = passes.count("trace") ? passes.at("trace").ms : none;
    double trace_ms = 0;
    for (size_t i = trace_seen; i < trace.size(); ++i) trace_ms += trace[i];
    const double gpu_ms = gpu_total - gpu_seen;
    gpu_seen = gpu_total;
    trace_seen = trace.size();
    const double frender = std::chrono::duration<double>(t2 - t1).count();
    out.render_s += frender;
    out.gpu_ms += gpu_ms;
    out.per_frame.push_back({{"frame", f},
                             {"setup_s", setup_s},
                             {"render_s", frender},
                             {"gpu_ms", gpu_ms},
                             {"trace_gpu_ms", trace_ms},
                             {"samples", img.samples},
                             {"discarded", img.counters.discarded_json()},
                             {"clamped_squares", img.counters.clamped_squares},
                             {"tracking", img.counters.tracking_json()}});
    out.counters += img.counters;
  };
  // A frame that fails leaves earlier frames' images undelivered: they are dropped with the run (their
  // callbacks refer to this function's locals).
  try {
    for (int f = first; f <= last; ++f) {
      auto t0 = clock::now();
      scene::Scene fs = use_frame(ctx, r, s, f, f == first);
      if (f == first) {
        gpu_seen = total_gpu_ms(*r);
        const auto& passes = r->pass_stats_so_far();
        trace_seen = passes.count("trace") ? passes.at("trace").ms.size() : 0;
      }
      for (const auto& n : r->notes())
        if (std::find(out.notes.begin(), out.notes.end(), n) == out.notes.end()) {
          if (loop.on_note) loop.on_note(n);
          out.notes.push_back(n);
        }
      auto t1 = clock::now();
      const double fsetup = std::chrono::duration<double>(t1 - t0).count();
      out.setup_s += fsetup;
      if (loop.on_frame_start) loop.on_frame_start(f, first, last);
      if (fs.render.time_budget_s > 0) {
        // One sample at a time until the budget is spent (at least one); two are in flight at most.
        const auto until = t1 + std::chrono::duration_cast<clock::duration>(
                                    std::chrono::duration<double>(fs.render.time_budget_s));
        do r->add_samples(1);
        while (clock::now() < until);
      } else {
        r->add_samples(fs.render.spp, loop.progress);
      }
      r->resolve_async([&arrived, f, fsetup, t1](Image img) { arrived(f, fsetup, t1, std::move(img)); });
    }
    r->finish();
  } catch (...) {
    if (r) r->discard();
    throw;
  }
  // What the estimator dropped or clamped, said once for the run (per frame in per_frame).
  for (const std::string& n : counter_notes(out.counters)) {
    if (loop.on_note) loop.on_note(n);
    out.notes.push_back(n);
  }
  out.stats = r->stats();
  return out;
}

nlohmann::json summary_of_stats(const nlohmann::json& st) {
  const double frames = st.contains("frames") && st["frames"].is_array() && !st["frames"].empty()
                            ? double(st["frames"].size())
                            : 1.0;
  nlohmann::json passes = nlohmann::json::object();
  double gpu = 0;
  const nlohmann::json all = st.value("passes", nlohmann::json::object());
  for (const auto& [name, p] : all.items()) {
    passes[name] = p.value("total_ms", 0.0) / frames;
    gpu += p.value("total_ms", 0.0) / frames;
  }
  nlohmann::json memory = st.value("memory", nlohmann::json::object());
  memory.erase("entries");
  // A `haze denoise` folder's stats.json has no samples and no render time: left out, not shown as 0.
  return {{"samples", st.value("samples", nlohmann::json())},
          {"frames", int(frames)},
          {"render_s", st.value("render_s", nlohmann::json())},
          {"gpu_ms_per_frame", gpu},
          {"passes", passes},
          {"memory", memory}};
}

std::string format_summary(const nlohmann::json& s) {
  const int frames = s.value("frames", 1);
  const nlohmann::json spp = s.value("samples", nlohmann::json()),
                       render = s.value("render_s", nlohmann::json());
  std::string out =
      fmt::format("{}{} frame{}{}, GPU {:.1f} ms per frame\n",
                  spp.is_number() ? fmt::format("{} spp, ", spp.dump()) : "", frames, frames == 1 ? "" : "s",
                  render.is_number() ? fmt::format(", {:.2f} s render", render.get<double>()) : "",
                  s.value("gpu_ms_per_frame", 0.0));
  auto largest = [](const nlohmann::json& obj) {
    std::vector<std::pair<std::string, double>> v;
    for (const auto& [k, x] : obj.items())
      if (x.is_number()) v.emplace_back(k, x.get<double>());
    std::stable_sort(v.begin(), v.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
    return v;
  };
  const auto passes = largest(s.value("passes", nlohmann::json::object()));
  double total = 0;
  for (const auto& [k, ms] : passes) total += ms;
  std::string top;
  for (size_t i = 0; i < std::min<size_t>(3, passes.size()); ++i)
    top += fmt::format("{}{} {:.2f} ms ({:.0f}%)", i ? ", " : "", passes[i].first, passes[i].second,
                       total > 0 ? 100 * passes[i].second / total : 0.0);
  out += fmt::format("most expensive passes (GPU ms per frame): {}\n", top.empty() ? "none timed" : top);
  const nlohmann::json memory = s.value("memory", nlohmann::json::object());
  std::string cats;
  for (const auto& [k, bytes] : largest(memory.value("per_category", nlohmann::json::object())))
    cats += fmt::format("{}{} {:.3g}", cats.empty() ? "" : ", ", k, bytes / 1e6);
  out += fmt::format("memory {:.3g} MB (peak {:.3g} MB), per category in MB: {}\n",
                     memory.value("total", 0.0) / 1e6, memory.value("peak", 0.0) / 1e6,
                     cats.empty() ? "none" : cats);
  return out;
}

}  // namespace haze::render
