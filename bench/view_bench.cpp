#include "bench/view_bench.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cstdlib>

#include "view/viewer.hpp"

namespace haze::bench {

using nlohmann::json;

json bench_view(const gpu::ContextOptions& co, const scene::Scene& s, const ViewBenchOptions& o) {
  const char* display = std::getenv("DISPLAY");
  if (!display || !*display)
    return {
        {"skipped", "no X display ($DISPLAY is not set); run it as scripts/xvfb.sh haze bench --only view"}};
  json seeds = json::array();
  std::vector<double> ratios;
  double wall_sum = 0, gpu_sum = 0;
  for (int seed = 1; seed <= o.seeds; ++seed) {
    scene::Scene sc = s;
    sc.render.seed = uint32_t(seed);
    view::ViewOptions vo;
    vo.spp = o.spp;
    vo.frames = o.warmup + o.frames;
    vo.scale = 2;
    const view::ViewRun run = view::run_view(sc, vo, co);
    double wall = 0, gpu = 0;
    int n = 0;
    for (const auto& f : run.stats["frames"]) {
      if (f["frame"].get<int>() < o.warmup || f["gpu_ms"].get<double>() <= 0) continue;
      wall += f["wall_ms"].get<double>();
      gpu += f["gpu_ms"].get<double>();
      ++n;
    }
    if (n == 0 || gpu <= 0) throw std::runtime_error("view bench: no frame was timed");
    ratios.push_back(wall / gpu);
    wall_sum += wall / n;
    gpu_sum += gpu / n;
    seeds.push_back({{"seed", seed},
                     {"frames", n},
                     {"wall_ms_per_frame", wall / n},
                     {"gpu_ms_per_frame", gpu / n},
                     {"wall_over_gpu", wall / gpu},
                     {"host_wait_ms", run.stats["host_wait_ms"]},
                     {"validation_messages", run.validation_messages}});
  }
  double mean = 0;
  for (double r : ratios) mean += r / double(ratios.size());
  return {{"size", {s.render.width, s.render.height}},
          {"spp_per_frame", o.spp},
          {"frames_in_flight", 2},
          {"seeds", seeds},
          {"wall_over_gpu",
           {{"mean", mean},
            {"min", *std::min_element(ratios.begin(), ratios.end())},
            {"max", *std::max_element(ratios.begin(), ratios.end())}}},
          {"wall_ms_per_frame", wall_sum / double(o.seeds)},
          {"gpu_ms_per_frame", gpu_sum / double(o.seeds)},
          {"goal", 1.15}};
}

void print_view(const json& j) {
  if (j.contains("skipped")) {
    fmt::print("viewer: skipped: {}\n", j["skipped"].get<std::string>());
    return;
  }
  const auto& r = j["wall_over_gpu"];
  fmt::print(
      "viewer at {}x{}, {} spp per frame, {} frames in flight: frame wall {:.1f} ms, GPU {:.1f} ms; wall / "
      "GPU "
      "{:.3f} (seeds {:.3f}..{:.3f}; goal <= {})\n",
      j["size"][0].get<int>(), j["size"][1].get<int>(), j["spp_per_frame"].get<int>(),
      j["frames_in_flight"].get<int>(), j["wall_ms_per_frame"].get<double>(),
      j["gpu_ms_per_frame"].get<double>(), r["mean"].get<double>(), r["min"].get<double>(),
      r["max"].get<double>(), j["goal"].get<double>());
}

}  // namespace haze::bench
