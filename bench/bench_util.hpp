// Timing helpers shared by the parts of `haze bench`: medians of GPU timestamps over repeated submissions
// after a warm-up (lavapipe compiles a pipeline on its first dispatch).
#pragma once

#include <functional>
#include <vector>

#include "gpu/gpu.hpp"

namespace haze::bench {

using Record = std::function<void(VkCommandBuffer)>;

// Median GPU time (ms) of `reps` submissions of `record`, after one warm-up submission.
double timed_median(gpu::Context& ctx, int reps, const Record& record);

// Median GPU times of several kernels measured in alternation (a, b, c, a, b, c, ...), each after its own
// warm-up, so that the machine's drift over minutes touches every kernel alike: what a ratio between them
// needs.
std::vector<double> timed_medians(gpu::Context& ctx, int reps, const std::vector<Record>& records);

}  // namespace haze::bench
