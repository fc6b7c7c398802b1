#include "lights/environment.hpp"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <ImfRgbaFile.h>
#include <fmt/format.h>
#include <stb/stb_image.h>
#include <stb/stb_image_write.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>

#include "gpu/error.hpp"
#include "shaders/glsl.hpp"

namespace haze::lights {

namespace {

namespace fs = std::filesystem;

constexpr size_t kMaxTexels = size_t(1) << 26;

bool is_exr(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char magic[4] = {};
  in.read(reinterpret_cast<char*>(magic), 4);
  return in.gcount() == 4 && magic[0] == 0x76 && magic[1] == 0x2f && magic[2] == 0x31 && magic[3] == 0x01;
}

// header_only: the checks of the header (size, channels) without reading the pixels.
void read_exr(const std::string& path, const std::string& where, EnvironmentMap& m, bool header_only) {
  try {
    Imf::InputFile file(path.c_str());
    const auto dw = file.header().dataWindow();
    const int64_t w = int64_t(dw.max.x) - dw.min.x + 1, h = int64_t(dw.max.y) - dw.min.y + 1;
    if (w <= 0 || h <= 0) throw Error(fmt::format("{}: the image is empty", where));
    if (size_t(w) * size_t(h) > kMaxTexels)
      throw Error(fmt::format("{}: {}x{} is over 2^26 texels; scale it down", where, w, h));
    const Imf::ChannelList& ch = file.header().channels();
    const bool rgb = ch.findChannel("R") && ch.findChannel("G") && ch.findChannel("B");
    if (!rgb && ch.findChannel("Y") && (ch.findChannel("RY") || ch.findChannel("BY"))) {
      // Luminance and chroma (always half): OpenEXR's RGBA interface converts them to RGB.
      if (header_only) return;
      m.width = uint32_t(w);
      m.height = uint32_t(h);
      Imf::RgbaInputFile yc(path.c_str());
      std::vector<Imf::Rgba> px(size_t(w) * h);
      yc.setFrameBuffer(px.data() - dw.min.x - int64_t(dw.min.y) * w, 1, size_t(w));
      yc.readPixels(dw.min.y, dw.max.y);
      m.texels.resize(px.size());
      for (size_t i = 0; i < px.size(); ++i)
        m.texels[i] = glm::vec3(float(px[i].r), float(px[i].g), float(px[i].b));
      return;
    }
    if (!rgb && !ch.findChannel("Y")) {
      std::string names;
      for (auto it = ch.begin(); it != ch.end(); ++it)
        names += std::string(names.empty() ? "" : ", ") + it.name();
      throw Error(fmt::format("{}: needs channels R, G, B (or Y), has {}; write the radiance as R, G, B",
                              where, names.empty() ? "none" : names));
    }
    if (header_only) return;
    m.width = uint32_t(w);
    m.height = uint32_t(h);
    std::vector<float> planes[3];
    Imf::FrameBuffer fb;
    const char* names[3] = {"R", "G", "B"};
    for (int c = 0; c < (rgb ? 3 : 1); ++c) {
      planes[c].resize(size_t(w) * h);
      char* base = reinterpret_cast<char*>(planes[c].data()) -
                   (int64_t(dw.min.x) + int64_t(dw.min.y) * w) * int64_t(sizeof(float));
      fb.insert(rgb ? names[c] : "Y", Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * w));
    }
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    m.texels.resize(size_t(w) * h);
    for (size_t i = 0; i < m.texels.size(); ++i)
      m.texels[i] = rgb ? glm::vec3(planes[0][i], planes[1][i], planes[2][i]) : glm::vec3(planes[0][i]);
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    std::string what = e.what();
    std::replace(what.begin(), what.end(), '\n', ' ');
    throw Error(fmt::format("{}: cannot read the OpenEXR file ({})", where, what));
  }
}

void read_stb(const std::string& path, const std::string& where, EnvironmentMap& m, bool header_only) {
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw Error(fmt::format("{}: cannot open: {}", where, std::strerror(errno)));
  std::unique_ptr<FILE, decltype(&std::fclose)> file(f, &std::fclose);
  int w = 0, h = 0, n = 0;
  if (!stbi_info_from_file(f, &w, &h, &n))
    throw Error(fmt::format("{}: cannot decode ({}); use OpenEXR (.exr), Radiance HDR (.hdr) or PNG", where,
                            gpu::printable(stbi_failure_reason())));
  if (w <= 0 || h <= 0) throw Error(fmt::format("{}: the image is empty", where));
  if (size_t(w) * size_t(h) > kMaxTexels)
    throw Error(fmt::format("{}: {}x{} is over 2^26 texels; scale it down", where, w, h));
  if (header_only) return;
  m.width = uint32_t(w);
  m.height = uint32_t(h);
  m.texels.resize(size_t(w) * h);
  const size_t count = m.texels.size() * 3;
  auto fill = [&](auto* data, auto decode) {
    if (!data)
      throw Error(fmt::format("{}: cannot decode ({}); the file may be truncated", where,
                              gpu::printable(stbi_failure_reason())));
    for (size_t i = 0; i < count; ++i) m.texels[i / 3][int(i % 3)] = decode(data[i]);
  };
  if (stbi_is_hdr_from_file(f)) {
    std::unique_ptr<float, decltype(&stbi_image_free)> data(stbi_loadf_from_file(f, &w, &h, &n, 3),
                                                            &stbi_image_free);
    fill(data.get(), [](float v) { return v; });
  } else if (stbi_is_16_bit_from_file(f)) {
    std::unique_ptr<stbi_us, decltype(&stbi_image_free)> data(stbi_load_from_file_16(f, &w, &h, &n, 3),
                                                              &stbi_image_free);
    fill(data.get(), [](stbi_us v) { return glsl::srgb_decode(float(v) / 65535.0f); });
  } else {
    std::unique_ptr<stbi_uc, decltype(&stbi_image_free)> data(stbi_load_from_file(f, &w, &h, &n, 3),
                                                              &stbi_image_free);
    fill(data.get(), [](stbi_uc v) { return glsl::srgb_decode(float(v) / 255.0f); });
  }
}

// Q_k = P_k + floor(S_k / S * (2^24 - P)): the fixed-point CDF of `f` (count entries, stride `stride`),
// where S_k sums f up to k and P_k counts the positive entries up to k. Each positive entry gets at least
// 1 / 2^24, zero entries get nothing, and the last entry is exactly 1. All zero: uniform.
void fixed_point_cdf(const double* f, size_t count, float* out) {
  double total = 0;
  uint64_t positive = 0;
  for (size_t k = 0; k < count; ++k) {
    total += f[k];
    positive += f[k] > 0 ? 1 : 0;
  }
  if (!(total > 0)) {
    for (size_t k = 0; k < count; ++k)
      out[k] = float(double(((k + 1) * kRandomOne) / count) / double(kRandomOne));
    return;
  }
  const double spread = double(kRandomOne - positive);
  double sum = 0;
  uint64_t seen = 0;
  for (size_t k = 0; k < count; ++k) {
    sum += f[k];
    seen += f[k] > 0 ? 1 : 0;
    const uint64_t q =
        k + 1 == count ? kRandomOne : std::min(kRandomOne, seen + uint64_t(std::floor(sum / total * spread)));
    out[k] = float(double(q) / double(kRandomOne));
  }
}

EnvironmentMap read_map(const std::string& path, const std::string& key, bool header_only) {
  const std::string where = fmt::format("{} {}", key, path);
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(fmt::format("{}: no such file; check the path", where));
  if (!fs::is_regular_file(path, ec))
    throw Error(fmt::format("{}: not a regular file; name an .exr, .hdr or .png image", where));
  EnvironmentMap m;
  if (is_exr(path))
    read_exr(path, where, m, header_only);
  else
    read_stb(path, where, m, header_only);
  if (header_only) return m;
  for (glm::vec3& t : m.texels)
    for (int c = 0; c < 3; ++c) {
      float& v = t[c];
      if (std::isnan(v))
        ++m.nan, v = 0;
      else if (std::isinf(v))
        ++m.inf, v = 0;
      else if (v < 0)
        ++m.negative, v = 0;
    }
  return m;
}

}  // namespace

EnvironmentMap read_environment_map(const std::string& path, const std::string& key) {
  return read_map(path, key, false);
}

void check_environment_map(const std::string& path, const std::string& key) {
  read_map(path, key, true);
}

void write_environment_map(const std::string& path, const EnvironmentMap& m) {
  const fs::path p(path);
  const std::string tmp =
      (p.parent_path() / fmt::format(".{}.tmp{}", p.filename().string(), getpid())).string();
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  try {
    if (ext == ".exr") {
      Imf::Header header(int(m.width), int(m.height));
      header.compression() = Imf::ZIP_COMPRESSION;
      Imf::FrameBuffer fb;
      char* base = const_cast<char*>(reinterpret_cast<const char*>(m.texels.data()));
      const char* names[3] = {"R", "G", "B"};
      for (int c = 0; c < 3; ++c) {
        header.channels().insert(names[c], Imf::Channel(Imf::FLOAT));
        fb.insert(names[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), sizeof(glm::vec3),
                                       sizeof(glm::vec3) * m.width));
      }
      Imf::OutputFile file(tmp.c_str(), header);
      file.setFrameBuffer(fb);
      file.writePixels(int(m.height));
    } else if (ext == ".hdr") {
      if (!stbi_write_hdr(tmp.c_str(), int(m.width), int(m.height), 3, &m.texels[0].x))
        throw Error(fmt::format("cannot write {}", path));
    } else {
      throw Error(fmt::format("cannot write {}: name an .exr or .hdr file", path));
    }
    fs::rename(tmp, path);
  } catch (const Error&) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  } catch (const std::exception& e) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw Error(fmt::format("cannot write {}: {}", path, e.what()));
  }
}

EnvironmentMap make_sky(const SkyParams& p) {
  EnvironmentMap m;
  m.width = p.width;
  m.height = p.height;
  m.texels.resize(size_t(p.width) * p.height);
  const double el = glm::radians(double(p.sun_elevation)), az = glm::radians(double(p.sun_azimuth));
  const glm::dvec3 sun(std::sin(az) * std::cos(el), std::sin(el), -std::cos(az) * std::cos(el));
  const double cos_sun = std::cos(glm::radians(0.5 * double(p.sun_size)));
  const int s = 4;  // s x s samples per texel: the disc's edge is antialiased
  for (uint32_t j = 0; j < p.height; ++j)
    for (uint32_t i = 0; i < p.width; ++i) {
      glm::dvec3 sum(0);
      for (int a = 0; a < s; ++a)
        for (int b = 0; b < s; ++b) {
          const double u = (i + (a + 0.5) / s) / p.width, v = (j + (b + 0.5) / s) / p.height;
          const double theta = M_PI * v, phi = 2 * M_PI * u;
          const glm::dvec3 d(-std::sin(phi) * std::sin(theta), std::cos(theta),
                             std::cos(phi) * std::sin(theta));
          glm::dvec3 L = d.y >= 0 ? glm::mix(glm::dvec3(p.horizon), glm::dvec3(p.zenith), std::sqrt(d.y))
                                  : glm::dvec3(p.ground);
          if (glm::dot(d, sun) >= cos_sun) L += glm::dvec3(p.sun_radiance);
          sum += L;
        }
      m.texels[size_t(j) * p.width + i] = glm::vec3(sum / double(s * s));
    }
  return m;
}

double texel_solid_angle(uint32_t j, uint32_t width, uint32_t height) {
  return 2 * M_PI / width * (std::cos(M_PI * j / height) - std::cos(M_PI * (j + 1) / height));
}

EnvironmentDistribution build_distribution(const EnvironmentMap& m) {
  EnvironmentDistribution d;
  d.width = m.width;
  d.height = m.height;
  d.conditional.resize(size_t(m.width) * m.height);
  d.marginal.resize(m.height);
  std::vector<double> f(m.width), rows(m.height);
  for (uint32_t j = 0; j < m.height; ++j) {
    const double sin_theta = std::sin(M_PI * (j + 0.5) / m.height);
    const double omega = texel_solid_angle(j, m.width, m.height);
    rows[j] = 0;
    for (uint32_t i = 0; i < m.width; ++i) {
      const glm::vec3 L = m.texels[size_t(j) * m.width + i];
      const double Y = glsl::luminance(L);
      // A texel whose luminance underflows float still has radiance: it keeps its floor in the CDF.
      f[i] = std::max(Y, glm::any(glm::greaterThan(L, glm::vec3(0))) ? DBL_MIN : 0.0) * sin_theta;
      rows[j] += f[i];
      d.integral += glm::dvec3(L) * omega;
      d.luminance_integral += Y * omega;
    }
    fixed_point_cdf(f.data(), m.width, &d.conditional[size_t(j) * m.width]);
  }
  fixed_point_cdf(rows.data(), m.height, d.marginal.data());
  return d;
}

}  // namespace haze::lights
