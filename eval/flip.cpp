// FLIP, LDR (HPG 2020) and HDR (EG 2021); the papers' symbols are kept in local names: qc, pc, pt, qf, w,
// cmax, the CSF's a1, b1, a2, b2, the tone mapper's k0..k5. docs/metrics.md lists every formula.
#include "eval/flip.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <stdexcept>

namespace haze::eval {

namespace {

using std::numbers::pi;
using Vec3 = std::array<double, 3>;

// LDR-FLIP parameters (HPG 2020, section 4): colour exponent, error-remapping knee and its height,
// feature exponent, and the peak-to-trough width of the human edge detector in degrees.
constexpr double qc = 0.7, pc = 0.4, pt = 0.95, qf = 0.5, w = 0.082;

// Linear sRGB to CIE XYZ (D65). The white point is the XYZ of RGB (1, 1, 1), so white has a* = b* = 0.
constexpr double rgb_to_xyz[3][3] = {{10135552.0 / 24577794, 8788810.0 / 24577794, 4435075.0 / 24577794},
                                     {2613072.0 / 12288897, 8788810.0 / 12288897, 887015.0 / 12288897},
                                     {1425312.0 / 73733382, 8788810.0 / 73733382, 70074185.0 / 73733382}};

Vec3 mul(const double (&m)[3][3], const Vec3& v) {
  return {m[0][0] * v[0] + m[0][1] * v[1] + m[0][2] * v[2], m[1][0] * v[0] + m[1][1] * v[1] + m[1][2] * v[2],
          m[2][0] * v[0] + m[2][1] * v[1] + m[2][2] * v[2]};
}

struct Colour {
  double xyz_to_rgb[3][3];
  Vec3 white;  // Xn, Yn, Zn
  Colour() {
    const auto& m = rgb_to_xyz;
    white = mul(m, {1, 1, 1});
    // Inverse by cofactors: one matrix in the source, its inverse derived from it.
    double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                 m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                 m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        int r0 = (j + 1) % 3, r1 = (j + 2) % 3, c0 = (i + 1) % 3, c1 = (i + 2) % 3;
        xyz_to_rgb[i][j] = (m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0]) / det;
      }
  }
};
const Colour& colour() {
  static const Colour c;
  return c;
}

// Y'CxCz: the linear (no cube root) opponent space the CSF is applied in (HPG 2020, section 4.1).
Vec3 xyz_to_ycxcz(const Vec3& xyz) {
  const Vec3& n = colour().white;
  double x = xyz[0] / n[0], y = xyz[1] / n[1], z = xyz[2] / n[2];
  return {116 * y - 16, 500 * (x - y), 200 * (y - z)};
}
Vec3 ycxcz_to_xyz(const Vec3& c) {
  const Vec3& n = colour().white;
  double y = (c[0] + 16) / 116;
  return {(y + c[1] / 500) * n[0], y * n[1], (y - c[2] / 200) * n[2]};
}

// CIE L*a*b* with the Hunt adjustment a*, b* scaled by 0.01 L* (less colour discrimination in the dark).
Vec3 hunt_lab(const Vec3& rgb) {
  const Vec3 xyz = mul(rgb_to_xyz, rgb);
  const Vec3& n = colour().white;
  constexpr double d = 6.0 / 29;
  auto f = [&](double t) { return t > d * d * d ? std::cbrt(t) : t / (3 * d * d) + 4.0 / 29; };
  double fx = f(xyz[0] / n[0]), fy = f(xyz[1] / n[1]), fz = f(xyz[2] / n[2]);
  double L = 116 * fy - 16;
  return {L, 0.01 * L * 500 * (fx - fy), 0.01 * L * 200 * (fy - fz)};
}

// HyAB: city-block lightness plus Euclidean chroma difference (Abasi et al. 2020).
double hyab(const Vec3& p, const Vec3& q) {
  return std::abs(p[0] - q[0]) + std::hypot(p[1] - q[1], p[2] - q[2]);
}

// cmax: the HyAB distance of the two most different colours of the gamut, green and blue, to the qc.
double cmax() {
  static const double c = std::pow(hyab(hunt_lab({0, 1, 0}), hunt_lab({0, 0, 1})), qc);
  return c;
}

// Colour error in [0, 1]: the lower pc of the range to [0, pt], the rest compressed into (pt, 1].
double remap_colour_error(double hyab_distance) {
  const double e = std::pow(hyab_distance, qc), knee = pc * cmax();
  return e < knee ? pt / knee * e : pt + (e - knee) / (cmax() - knee) * (1 - pt);
}

struct Plane {
  int width = 0, height = 0;
  std::vector<float> v;
  Plane(int w_, int h_, float fill = 0) : width(w_), height(h_), v(size_t(w_) * h_, fill) {}
};

// 1D taps w[i] for offsets i - r, i = 0..2r.
struct Kernel {
  int r = 0;
  std::vector<double> w;
};

// One separable pass along x or y, borders replicated: keep * v + sum_i w_i (v_{x+i} - v_x). The same as
// sum_i w_i v_{x+i} when the taps sum to keep (1 for blurs, 0 for derivatives), written so that flat
// regions come out exact: identical images must give exactly zero and flat ones exactly no features.
Plane pass(const Plane& in, const Kernel& k, bool along_x, bool keep) {
  const int W = in.width, H = in.height, r = k.r;
  const std::vector<float> kw(k.w.begin(), k.w.end());  // float taps and sums: twice as fast, 1e-7 off
  Plane out(W, H);
  std::vector<float> acc(size_t(std::max(W, 0)));
  std::vector<float> line(size_t(W + 2 * r));
  for (int y = 0; y < H; ++y) {
    const float* row = &in.v[size_t(y) * W];
    std::fill(acc.begin(), acc.end(), 0.f);
    if (along_x) {
      for (int x = -r; x < W + r; ++x) line[size_t(x + r)] = row[std::clamp(x, 0, W - 1)];
      for (int i = 0; i <= 2 * r; ++i)
        for (int x = 0; x < W; ++x) acc[size_t(x)] += kw[size_t(i)] * (line[size_t(x + i)] - row[x]);
    } else {
      for (int i = 0; i <= 2 * r; ++i) {
        const float* other = &in.v[size_t(std::clamp(y + i - r, 0, H - 1)) * W];
        for (int x = 0; x < W; ++x) acc[size_t(x)] += kw[size_t(i)] * (other[x] - row[x]);
      }
    }
    for (int x = 0; x < W; ++x) out.v[size_t(y) * W + x] = float((keep ? row[x] : 0.0) + acc[size_t(x)]);
  }
  return out;
}

Plane separable(const Plane& in, const Kernel& kx, bool keep_x, const Kernel& ky, bool keep_y) {
  return pass(pass(in, kx, true, keep_x), ky, false, keep_y);
}

// The CSF of one opponent channel as a sum of Gaussians a sqrt(pi / b) exp(-pi^2 d^2 / b), d in degrees
// (HPG 2020, eq. 2, parameters from table 1 of the paper; a2 = 0 for A and RG).
struct Csf {
  double a1, b1, a2, b2;
};
constexpr Csf csf_A{1, 0.0047, 0, 1e-5}, csf_RG{1, 0.0053, 0, 1e-5}, csf_BY{34.1, 0.04, 13.5, 0.025};

// Filters one channel with its CSF over a square window of radius r (the same for all channels, from
// the widest Gaussian: 3 standard deviations of the largest b). Each Gaussian term is separable; the window's
// 2D weights are normalized to sum 1, which makes term k weigh a_k sqrt(pi / b_k) G_k^2 / S with G_k its
// 1D sum and S the 2D sum.
Plane csf_filter(const Plane& in, const Csf& c, double ppd) {
  const double b_max = std::max({csf_A.b1, csf_A.b2, csf_RG.b1, csf_RG.b2, csf_BY.b1, csf_BY.b2});
  const int r = int(std::ceil(3 * std::sqrt(b_max / (2 * pi * pi)) * ppd));
  struct Term {
    double weight;
    Kernel k;
  };
  std::vector<Term> terms;
  double S = 0;
  for (auto [a, b] : {std::pair{c.a1, c.b1}, std::pair{c.a2, c.b2}}) {
    if (a == 0) continue;
    Kernel k{r, std::vector<double>(size_t(2 * r + 1))};
    double G = 0;
    for (int i = -r; i <= r; ++i) G += k.w[size_t(i + r)] = std::exp(-pi * pi * (i / ppd) * (i / ppd) / b);
    for (double& t : k.w) t /= G;
    const double weight = a * std::sqrt(pi / b) * G * G;
    S += weight;
    terms.push_back({weight, std::move(k)});
  }
  // out = v + sum_k weight_k / S (blur_k(v) - v): exact on flat regions like pass().
  Plane out = in;
  for (const auto& t : terms) {
    Plane blurred = separable(in, t.k, true, t.k, true);
    for (size_t p = 0; p < out.v.size(); ++p)
      out.v[p] = float(out.v[p] + t.weight / S * (double(blurred.v[p]) - in.v[p]));
  }
  return out;
}

// Feature detectors (HPG 2020, section 4.2): first (edges) and second (points) x-derivatives of a
// Gaussian with sd = 0.5 w ppd, positive taps scaled to sum 1 and negative to -1. The 2D filter is the
// 1D derivative across and the normalized Gaussian along; the y-filter is its transpose.
struct Features {
  Kernel gauss, edge, point;
  explicit Features(double ppd) {
    const double sd = 0.5 * w * ppd;
    const int r = int(std::ceil(3 * sd));
    gauss = edge = point = {r, std::vector<double>(size_t(2 * r + 1))};
    double G = 0;
    for (int i = -r; i <= r; ++i) {
      double g = std::exp(-double(i * i) / (2 * sd * sd));
      G += gauss.w[size_t(i + r)] = g;
      edge.w[size_t(i + r)] = -i * g;
      point.w[size_t(i + r)] = (i * i / (sd * sd) - 1) * g;
    }
    for (double& t : gauss.w) t /= G;
    for (Kernel* k : {&edge, &point}) {
      double pos = 0, neg = 0;
      for (double t : k->w) (t > 0 ? pos : neg) += t;
      for (double& t : k->w) t = t > 0 ? t / pos : t / -neg;
    }
  }
  // |gradient| and |second derivative| vectors (x, y) per pixel of the luminance y.
  std::pair<Plane, Plane> magnitudes(const Plane& y) const {
    const Plane gx = pass(y, gauss, true, true);
    Plane ex = separable(y, edge, false, gauss, true), ey = pass(gx, edge, false, false);
    Plane px = separable(y, point, false, gauss, true), py = pass(gx, point, false, false);
    for (size_t p = 0; p < ex.v.size(); ++p) {
      ex.v[p] = std::hypot(ex.v[p], ey.v[p]);
      px.v[p] = std::hypot(px.v[p], py.v[p]);
    }
    return {std::move(ex), std::move(px)};
  }
};

// One image prepared for LDR-FLIP: its CSF-filtered Hunt-adjusted L*a*b* and its feature magnitudes.
struct Prepared {
  Plane L, A, B, edges, points;
};

// rgb: linear values already in [0, 1].
Prepared prepare(const std::array<Plane, 3>& rgb, double ppd, const Features& features) {
  const int W = rgb[0].width, H = rgb[0].height;
  Plane y(W, H), cx(W, H), cz(W, H), lum(W, H);
  for (size_t p = 0; p < y.v.size(); ++p) {
    const Vec3 xyz = mul(rgb_to_xyz, {rgb[0].v[p], rgb[1].v[p], rgb[2].v[p]});
    const Vec3 o = xyz_to_ycxcz(xyz);
    y.v[p] = float(o[0]);
    cx.v[p] = float(o[1]);
    cz.v[p] = float(o[2]);
    lum.v[p] = float(xyz[1] / colour().white[1]);  // the normalized achromatic channel (Y' + 16) / 116
  }
  y = csf_filter(y, csf_A, ppd);
  cx = csf_filter(cx, csf_RG, ppd);
  cz = csf_filter(cz, csf_BY, ppd);
  Prepared out{Plane(W, H), Plane(W, H), Plane(W, H), Plane(0, 0), Plane(0, 0)};
  for (size_t p = 0; p < y.v.size(); ++p) {
    Vec3 c = mul(colour().xyz_to_rgb, ycxcz_to_xyz({y.v[p], cx.v[p], cz.v[p]}));
    for (double& v : c) v = std::clamp(v, 0.0, 1.0);  // filtering may leave the RGB cube
    const Vec3 lab = hunt_lab(c);
    out.L.v[p] = float(lab[0]);
    out.A.v[p] = float(lab[1]);
    out.B.v[p] = float(lab[2]);
  }
  std::tie(out.edges, out.points) = features.magnitudes(lum);
  return out;
}

void check(const Channels& test, const Channels& ref, int width, int height, const FlipOptions& o) {
  if (!(o.ppd > 0 && o.ppd < 1e4)) throw std::invalid_argument("flip: ppd must be in (0, 1e4)");
  const size_t n = size_t(std::max(width, 0)) * size_t(std::max(height, 0));
  if (width <= 0 || height <= 0 || test.pixels != n || ref.pixels != n)
    throw std::invalid_argument("flip: images differ from width x height");
  if (test.count != ref.count || !flip_supports(ref.count))
    throw std::invalid_argument("flip: needs two images of 1 (grey) or 3 (RGB) channels");
}

// Linear RGB planes of an image after per-value f (grey: the one channel thrice).
template <class F>
std::array<Plane, 3> planes(const Channels& c, int width, int height, F&& f) {
  std::array<Plane, 3> rgb{Plane(width, height), Plane(width, height), Plane(width, height)};
  for (size_t p = 0; p < c.pixels; ++p)
    for (uint32_t k = 0; k < 3; ++k) rgb[k].v[p] = float(f(double(c.at(p, c.count == 1 ? 0 : k))));
  return rgb;
}

// Per-pixel LDR-FLIP of two prepared images: e = colour_error^(1 - feature_error).
std::vector<float> ldr_map(const Prepared& t, const Prepared& r) {
  std::vector<float> e(t.L.v.size());
  for (size_t p = 0; p < e.size(); ++p) {
    const double colour_error =
        remap_colour_error(hyab({t.L.v[p], t.A.v[p], t.B.v[p]}, {r.L.v[p], r.A.v[p], r.B.v[p]}));
    const double feature_difference = std::max(std::abs(double(t.edges.v[p]) - r.edges.v[p]),
                                               std::abs(double(t.points.v[p]) - r.points.v[p]));
    const double feature_error = std::pow(feature_difference / std::sqrt(2.0), qf);
    // cmax is the gamut's largest distance: the clamp only guards rounding.
    e[p] = float(std::clamp(std::pow(colour_error, 1 - feature_error), 0.0, 1.0));
  }
  return e;
}

FlipResult finish(std::vector<float>&& map, bool want_map) {
  FlipResult res;
  double sum = 0;
  for (float v : map) sum += v;
  res.mean = map.empty() ? 0.0 : sum / double(map.size());
  if (want_map) res.map = std::move(map);
  return res;
}

// The ACES filmic curve (Narkowicz's fit) the HDR paper assumes, with its 0.6 pre-exposure folded in:
// tm(x) = (k0 x^2 + k1 x + k2) / (k3 x^2 + k4 x + k5), clamped to [0, 1].
constexpr double k0 = 0.6 * 0.6 * 2.51, k1 = 0.6 * 0.03, k2 = 0, k3 = 0.6 * 0.6 * 2.43, k4 = 0.6 * 0.59,
                 k5 = 0.14;
double tone_map(double x) {
  const double y = (k0 * x * x + k1 * x + k2) / (k3 * x * x + k4 * x + k5);
  return std::isfinite(y) ? std::clamp(y, 0.0, 1.0) : 1.0;
}
// The x that the tone mapper takes to t: the positive root of (k0 - k3 t) x^2 + (k1 - k4 t) x + k2 - k5 t.
double tone_map_inverse(double t) {
  const double c0 = (k1 - k4 * t) / (k0 - k3 * t), c1 = (k2 - k5 * t) / (k0 - k3 * t);
  return -0.5 * c0 + std::sqrt(0.25 * c0 * c0 - c1);
}

}  // namespace

bool flip_supports(uint32_t channel_count) {
  return channel_count == 1 || channel_count >= 3;
}

FlipResult flip_ldr(const Channels& test, const Channels& ref, int width, int height, const FlipOptions& o) {
  check(test, ref, width, height, o);
  auto clamp01 = [](double v) { return std::clamp(v, 0.0, 1.0); };  // HDR input: above 1 reads as 1
  const Features features(o.ppd);
  return finish(ldr_map(prepare(planes(test, width, height, clamp01), o.ppd, features),
                        prepare(planes(ref, width, height, clamp01), o.ppd, features)),
                o.want_map);
}

FlipExposures flip_hdr_exposures(const Channels& ref) {
  // Exposure range (EG 2021, section 3): the start exposure takes the reference's brightest luminance,
  // the stop exposure its median, to t = 0.85 of the tone mapper's range.
  constexpr double t_max = 0.85, t_min = 0.85;
  std::vector<double> Y(ref.pixels);
  for (size_t p = 0; p < ref.pixels; ++p)
    Y[p] =
        ref.count == 1 ? ref.at(p, 0) : 0.2126 * ref.at(p, 0) + 0.7152 * ref.at(p, 1) + 0.0722 * ref.at(p, 2);
  const double Y_max = Y.empty() ? 0 : *std::max_element(Y.begin(), Y.end());
  FlipExposures e;
  if (Y_max > 0) {
    // Median as NVIDIA's FLIP C++ tool takes it: the sorted value at index n/2 (for even n the upper
    // of the middle two, not their mean). Departure from the paper: where more than half the reference
    // is black the median is 0 and the range infinite, so the median of the positive luminances stands in.
    std::vector<double> y = Y;
    if (std::count_if(y.begin(), y.end(), [](double v) { return v > 0; }) * 2 <= ptrdiff_t(y.size()))
      std::erase_if(y, [](double v) { return v <= 0; });
    std::nth_element(y.begin(), y.begin() + y.size() / 2, y.end());
    const double Y_median = y[y.size() / 2];
    e.start = std::log2(tone_map_inverse(t_max) / Y_max);
    e.stop = Y_median > 0 ? std::log2(tone_map_inverse(t_min) / Y_median) : e.start;
  }
  e.count = std::max(2, int(std::ceil(e.stop - e.start)));
  return e;
}

FlipResult flip_hdr(const Channels& test, const Channels& ref, int width, int height, const FlipOptions& o) {
  check(test, ref, width, height, o);
  const auto [start, stop, exposures] = flip_hdr_exposures(ref);
  const double step = (stop - start) / (exposures - 1);

  const Features features(o.ppd);
  std::vector<float> map(ref.pixels, 0.f);
  for (int i = 0; i < exposures; ++i) {
    const double scale = std::exp2(start + i * step);
    auto exposed = [scale](double v) { return tone_map(scale * std::max(v, 0.0)); };
    std::vector<float> e = ldr_map(prepare(planes(test, width, height, exposed), o.ppd, features),
                                   prepare(planes(ref, width, height, exposed), o.ppd, features));
    for (size_t p = 0; p < map.size(); ++p) map[p] = std::max(map[p], e[p]);
  }
  return finish(std::move(map), o.want_map);
}

std::vector<uint32_t> magma_rgba8(const std::vector<float>& map) {
  // matplotlib's magma (van der Walt and Smith, BIDS/colormap, CC0): entries 0, 17, ..., 255 of its
  // 256, linearly interpolated (at most 2.3/255 from the full table).
  static constexpr float magma[16][3] = {
      {0.001462f, 0.000466f, 0.013866f}, {0.043830f, 0.033830f, 0.141886f}, {0.123833f, 0.067295f, 0.295879f},
      {0.232077f, 0.059889f, 0.437695f}, {0.341482f, 0.080564f, 0.492631f}, {0.445163f, 0.122724f, 0.506901f},
      {0.550287f, 0.161158f, 0.505719f}, {0.658483f, 0.196027f, 0.490253f}, {0.767398f, 0.233705f, 0.457755f},
      {0.868793f, 0.287728f, 0.409303f}, {0.944006f, 0.377643f, 0.365136f}, {0.981000f, 0.498428f, 0.369734f},
      {0.994738f, 0.624350f, 0.427397f}, {0.997228f, 0.747981f, 0.516859f}, {0.993170f, 0.870024f, 0.626189f},
      {0.987053f, 0.991438f, 0.749504f}};
  std::vector<uint32_t> rgba(map.size());
  for (size_t p = 0; p < map.size(); ++p) {
    const float t = std::clamp(std::isfinite(map[p]) ? map[p] : 1.f, 0.f, 1.f) * 15.f;
    const int i = std::min(int(t), 14);
    const float f = t - float(i);
    uint32_t px = 0xff000000u;  // alpha; bytes R, G, B, A in memory
    for (int c = 0; c < 3; ++c) {
      const float v = magma[i][c] + f * (magma[i + 1][c] - magma[i][c]);
      px |= uint32_t(std::lround(std::clamp(v, 0.f, 1.f) * 255.f)) << (8 * c);
    }
    rgba[p] = px;
  }
  return rgba;
}

}  // namespace haze::eval
