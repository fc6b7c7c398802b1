#include "eval/metrics.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

namespace haze::eval {

namespace {

// Mean over pixels and channels of f(x, r).
template <class F>
double mean_of(const Channels& x, const Channels& ref, F&& f) {
  if (x.pixels != ref.pixels || x.count != ref.count)
    throw std::invalid_argument("metrics: images differ in size or channel count");
  double sum = 0;
  for (size_t p = 0; p < x.pixels; ++p)
    for (uint32_t c = 0; c < x.count; ++c) sum += f(double(x.at(p, c)), double(ref.at(p, c)));
  const double n = double(x.pixels) * x.count;
  return n > 0 ? sum / n : 0.0;
}

}  // namespace

double relmse(const Channels& x, const Channels& ref) {
  return mean_of(x, ref, relmse_term);
}

double smape(const Channels& x, const Channels& ref) {
  return mean_of(x, ref,
                 [](double a, double r) { return std::abs(a - r) / (std::abs(a) + std::abs(r) + 0.01); });
}

double mse(const Channels& x, const Channels& ref) {
  return mean_of(x, ref, [](double a, double r) { return (a - r) * (a - r); });
}

double psnr(double m) {
  return m > 0 ? 10.0 * std::log10(1.0 / m) : std::numeric_limits<double>::infinity();
}

Metrics compare(const Channels& x, const Channels& ref) {
  Metrics m;
  m.relmse = relmse(x, ref);
  m.smape = smape(x, ref);
  m.mse = mse(x, ref);
  m.psnr = psnr(m.mse);
  return m;
}

nlohmann::json Metrics::to_json() const {
  return {{"relmse", relmse},
          {"smape", smape},
          {"mse", mse},
          {"psnr", std::isinf(psnr) ? nlohmann::json("inf") : nlohmann::json(psnr)}};
}

Temporal temporal(const std::vector<Channels>& x, const std::vector<Channels>& ref) {
  if (x.size() != ref.size()) throw std::invalid_argument("metrics: sequences differ in length");
  Temporal t;
  double abs_dx = 0, abs_dr = 0, rel = 0;
  size_t n = 0;
  for (size_t f = 1; f < x.size(); ++f) {
    const Channels &x0 = x[f - 1], &x1 = x[f], &r0 = ref[f - 1], &r1 = ref[f];
    if (x0.pixels != r1.pixels || x1.pixels != r1.pixels || r0.pixels != r1.pixels)
      throw std::invalid_argument("metrics: frames differ in size");
    for (size_t p = 0; p < x1.pixels; ++p)
      for (uint32_t c = 0; c < x1.count; ++c) {
        double dx = double(x1.at(p, c)) - x0.at(p, c), dr = double(r1.at(p, c)) - r0.at(p, c);
        double r = r1.at(p, c);
        rel += (dx - dr) * (dx - dr) / relmse_denominator(r);
        abs_dx += std::abs(dx);
        abs_dr += std::abs(dr);
        ++n;
      }
  }
  t.relmse_of_change = n ? rel / double(n) : 0.0;
  t.change_ratio =
      abs_dr > 0 ? abs_dx / abs_dr : (abs_dx > 0 ? std::numeric_limits<double>::infinity() : 1.0);
  return t;
}

nlohmann::json Temporal::to_json() const {
  return {{"relmse_of_change", relmse_of_change},
          {"change_ratio", std::isinf(change_ratio) ? nlohmann::json("inf") : nlohmann::json(change_ratio)}};
}

}  // namespace haze::eval
