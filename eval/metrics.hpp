// Error metrics against a reference (docs/metrics.md), for `haze compare`, `haze bench` and sweeps.
// Each metric averages over pixels and channels; the formula of each is in metrics.cpp, once.
#pragma once

#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace haze::eval {

// Channels of one image, each `pixels` floats apart from `stride`/`offset` addressing: channel c of pixel
// p is data[p * stride + offset + c]. Lets a resolved Image's layers be compared in place.
struct Channels {
  const float* data = nullptr;
  size_t pixels = 0;
  uint32_t stride = 3, offset = 0, count = 3;
  float at(size_t p, uint32_t c) const { return data[p * stride + offset + c]; }
};

// relMSE = mean (x - r)^2 / (r^2 + 0.01). Its denominator, and the term of one value (for per-pixel maps
// and the references' standard error):
inline double relmse_denominator(double r) {
  return r * r + 0.01;
}
inline double relmse_term(double x, double r) {
  return (x - r) * (x - r) / relmse_denominator(r);
}
double relmse(const Channels& x, const Channels& ref);
// SMAPE = mean |x - r| / (|x| + |r| + 0.01).
double smape(const Channels& x, const Channels& ref);
// MSE = mean (x - r)^2.
double mse(const Channels& x, const Channels& ref);
// PSNR = 10 log10(1 / MSE) (peak 1: the values as stored); +inf for identical images.
double psnr(double mse);

struct Metrics {
  double relmse = 0, smape = 0, mse = 0, psnr = 0;
  nlohmann::json to_json() const;  // PSNR of identical images is written as the string "inf"
};
Metrics compare(const Channels& x, const Channels& ref);

// Temporal stability of a sequence against its reference sequence (frames in order, same sizes): the
// frame-to-frame changes dx_f = x_f - x_{f-1} and dr_f = r_f - r_{f-1}.
struct Temporal {
  double relmse_of_change = 0;  // mean over f >= 1 of relMSE-style (dx - dr)^2 / (r_f^2 + 0.01)
  double change_ratio = 0;      // mean |dx| / mean |dr|: 1 = as much flicker as the reference
  nlohmann::json to_json() const;
};
Temporal temporal(const std::vector<Channels>& x, const std::vector<Channels>& ref);

}  // namespace haze::eval
