// Helpers shared by the parts of `haze bench`: medians of GPU timestamps over repeated submissions after a
// warm-up (lavapipe compiles a pipeline on its first dispatch), the signals the error figures compare, and
// their summaries over seeds.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <vector>

#include "eval/metrics.hpp"
#include "gpu/gpu.hpp"
#include "render/renderer.hpp"

namespace haze::bench {

using Record = std::function<void(VkCommandBuffer)>;

// Median GPU time (ms) of `reps` submissions of `record`, after one warm-up submission.
double timed_median(gpu::Context& ctx, int reps, const Record& record);

// Median GPU times of several kernels measured in alternation (a, b, c, a, b, c, ...), each after its own
// warm-up, so that the machine's drift over minutes touches every kernel alike: what a ratio between them
// needs.
std::vector<double> timed_medians(gpu::Context& ctx, int reps, const std::vector<Record>& records);

// The volume signal of a resolved image, and the volume instance's denoised output, for eval::relmse.
eval::Channels volume_of(const render::Image& img);
eval::Channels denoised_volume_of(const render::Image& img);

// {mean, min, max, values} of a list of figures (over seeds).
nlohmann::json summary(const std::vector<double>& v);

}  // namespace haze::bench
