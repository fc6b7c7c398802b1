// Error metrics against a reference (DESIGN.md section 7). Inputs are rgb triples, `stride` floats per
// pixel with the rgb at `offset` (so a resolved Image's layers can be compared in place).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace haze::render {

struct Channels {
  const float* data = nullptr;
  size_t pixels = 0;
  uint32_t stride = 3, offset = 0;
  float at(size_t p, int c) const { return data[p * stride + offset + c]; }
};

// relMSE = mean over pixels and channels of (x - r)^2 / (r^2 + 0.01).
inline double relmse(const Channels& x, const Channels& ref) {
  double sum = 0;
  for (size_t p = 0; p < x.pixels; ++p)
    for (int c = 0; c < 3; ++c) {
      double d = double(x.at(p, c)) - ref.at(p, c), r = ref.at(p, c);
      sum += d * d / (r * r + 0.01);
    }
  return x.pixels ? sum / (3.0 * x.pixels) : 0.0;
}

}  // namespace haze::render
