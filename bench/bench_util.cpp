#include "bench/bench_util.hpp"

#include <algorithm>
#include <numeric>

#include "render/renderer.hpp"

namespace haze::bench {

std::vector<double> timed_medians(gpu::Context& ctx, int reps, const std::vector<Record>& records) {
  gpu::Timer timer(ctx, 4);
  std::vector<std::vector<double>> ms(records.size());
  for (int i = 0; i < reps + 1; ++i)
    for (size_t k = 0; k < records.size(); ++k) {
      ctx.submit_and_wait([&](VkCommandBuffer cmd) {
        timer.reset(cmd);
        timer.begin(cmd, "bench");
        records[k](cmd);
        timer.end(cmd);
      });
      const double t = timer.read_ms().at(0).second;
      if (i > 0) ms[k].push_back(t);
    }
  std::vector<double> out;
  for (auto& v : ms) out.push_back(render::median(v));
  return out;
}

double timed_median(gpu::Context& ctx, int reps, const Record& record) {
  return timed_medians(ctx, reps, {record}).at(0);
}

eval::Channels volume_of(const render::Image& img) {
  return {img.data.data(), size_t(img.width) * img.height, glsl::OUT_STRIDE, glsl::OUT_VOL};
}

eval::Channels denoised_volume_of(const render::Image& img) {
  return {&img.volume_denoised->colour[0].x, size_t(img.width) * img.height, 3, 0};
}

nlohmann::json summary(const std::vector<double>& v) {
  return {{"mean", std::accumulate(v.begin(), v.end(), 0.0) / double(v.size())},
          {"min", *std::min_element(v.begin(), v.end())},
          {"max", *std::max_element(v.begin(), v.end())},
          {"values", v}};
}

}  // namespace haze::bench
