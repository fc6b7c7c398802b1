#include "render/output.hpp"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfVecAttribute.h>
#include <fmt/format.h>
#include <stb/stb_image_write.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace haze::render {

namespace fs = std::filesystem;

const std::vector<Layer>& exr_layers() {
  using namespace glsl;
  auto out = [](uint32_t offset) {
    return [offset](const Image& img, size_t p, int c) { return img.data[p * OUT_STRIDE + offset + c]; };
  };
  auto gbuf = [](uint32_t offset) {
    return [offset](const Image& img, size_t p, int c) { return img.gbuffer[p * G_STRIDE + offset + c]; };
  };
  auto has_denoised = [](const Image& img) { return img.surface_denoised.has_value(); };
  auto has_volume_denoised = [](const Image& img) { return img.volume_denoised.has_value(); };
  static const std::vector<Layer> layers = {
      {"", {"R", "G", "B"}, out(OUT_L)},
      {"volume", {"R", "G", "B"}, out(OUT_VOL)},
      {"surface", {"R", "G", "B"}, out(OUT_SURF)},
      {"surface_demod", {"R", "G", "B"}, out(OUT_DEMOD)},
      {"surface_demod_m2", {"R", "G", "B"}, out(OUT_DEMOD_M2)},
      {"surface_emission",
       {"R", "G", "B"},
       out(OUT_EMIT),
       [](const Image& img) { return img.surface_emission; }},
      {"transmittance", {"Y"}, out(OUT_T)},
      {"variance", {"R", "G", "B"}, out(OUT_VAR)},
      {"depth", {"Z"}, gbuf(G_DEPTH)},
      {"depth_gradient", {"X", "Y"}, gbuf(G_DDEPTH)},
      {"normal",
       {"X", "Y", "Z"},
       [](const Image& img, size_t p, int c) {
         const float* g = &img.gbuffer[p * G_STRIDE + G_NORMAL];
         return oct_decode(vec2(g[0], g[1]))[c];
       }},
      {"albedo", {"R", "G", "B"}, gbuf(G_ALBEDO)},
      {"instance",
       {"ID"},
       [](const Image& img, size_t p, int) {
         uint32_t id = floatBitsToUint(img.gbuffer[p * G_STRIDE + G_INSTANCE]);
         return id == 0xffffffffu ? -1.f : float(id);
       }},
      {"motion", {"X", "Y"}, gbuf(G_MOTION)},
      {"depth_prev", {"Z"}, gbuf(G_PREV_DEPTH)},
      {"virtual_point_depth", {"Z"}, out(OUT_VPDEPTH)},
      {"volume_motion",
       {"X", "Y"},
       [](const Image& img, size_t p, int c) { return img.volume_motion[p][c]; },
       [](const Image& img) { return !img.volume_motion.empty(); }},
      // The composite of the denoised signals: surface (remodulated, with its transmittance) + volume, each
      // the noisy mean where its instance did not run.
      {"denoised",
       {"R", "G", "B"},
       [](const Image& img, size_t p, int c) {
         float s = img.surface_denoised ? img.surface_denoised->colour[p][c]
                                        : img.data[p * OUT_STRIDE + OUT_SURF + c];
         float v =
             img.volume_denoised ? img.volume_denoised->colour[p][c] : img.data[p * OUT_STRIDE + OUT_VOL + c];
         return s + v;
       },
       [](const Image& img) { return img.surface_denoised.has_value() || img.volume_denoised.has_value(); }},
      // Each instance's output (after TAA), its history length and the variance of its filtered luminance.
      {"surface_denoised",
       {"R", "G", "B"},
       [](const Image& img, size_t p, int c) { return img.surface_denoised->colour[p][c]; },
       has_denoised},
      {"surface_history",
       {"Y"},
       [](const Image& img, size_t p, int) { return img.surface_denoised->history[p]; },
       has_denoised},
      {"surface_denoised_variance",
       {"Y"},
       [](const Image& img, size_t p, int) { return img.surface_denoised->variance[p]; },
       has_denoised},
      {"volume_denoised",
       {"R", "G", "B"},
       [](const Image& img, size_t p, int c) { return img.volume_denoised->colour[p][c]; },
       has_volume_denoised},
      {"volume_history",
       {"Y"},
       [](const Image& img, size_t p, int) { return img.volume_denoised->history[p]; },
       has_volume_denoised},
      {"volume_denoised_variance",
       {"Y"},
       [](const Image& img, size_t p, int) { return img.volume_denoised->variance[p]; },
       has_volume_denoised},
  };
  return layers;
}

namespace {

constexpr const char* kEpipoleAttribute = "haze.epipole";

std::string temp_path_for(const std::string& path) {
  fs::path p(path);
  return (p.parent_path() / fmt::format(".{}.tmp{}", p.filename().string(), getpid())).string();
}

// Runs write(tmp) and renames tmp onto path; removes tmp on failure.
template <class F>
void atomic_write(const std::string& path, F&& write) {
  std::string tmp = temp_path_for(path);
  try {
    write(tmp);
    fs::rename(tmp, path);
  } catch (const std::exception& e) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw Error(fmt::format("cannot write {}: {}", path, e.what()));
  }
}

}  // namespace

void write_exr_channels(const std::string& path, int width, int height,
                        const std::vector<std::pair<std::string, const std::vector<float>*>>& channels,
                        const std::optional<glm::vec3>& epipole) {
  Imf::Header header(width, height);
  header.compression() = Imf::ZIP_COMPRESSION;
  if (epipole)
    header.insert(kEpipoleAttribute, Imf::V3fAttribute(Imath::V3f(epipole->x, epipole->y, epipole->z)));
  Imf::FrameBuffer fb;
  for (const auto& [name, plane] : channels) {
    if (plane->size() != size_t(width) * height)
      throw Error(fmt::format("cannot write {}: channel {} has {} values for {}x{}", path, name,
                              plane->size(), width, height));
    header.channels().insert(name, Imf::Channel(Imf::FLOAT));
    fb.insert(name, Imf::Slice(Imf::FLOAT, const_cast<char*>(reinterpret_cast<const char*>(plane->data())),
                               sizeof(float), sizeof(float) * width));
  }
  atomic_write(path, [&](const std::string& tmp) {
    Imf::OutputFile file(tmp.c_str(), header);
    file.setFrameBuffer(fb);
    file.writePixels(height);
  });
}

std::vector<std::pair<std::string, std::vector<float>>> exr_planes(const Image& img) {
  const size_t pixels = size_t(img.width) * img.height;
  std::vector<std::pair<std::string, std::vector<float>>> planes;
  for (const Layer& l : exr_layers()) {
    if (!l.present(img)) continue;
    for (size_t c = 0; c < l.channels.size(); ++c) {
      planes.emplace_back(l.name.empty() ? l.channels[c] : l.name + "." + l.channels[c],
                          std::vector<float>(pixels));
      for (size_t p = 0; p < pixels; ++p) planes.back().second[p] = l.value(img, p, int(c));
    }
  }
  return planes;
}

void write_exr(const std::string& path, const Image& img) {
  const auto planes = exr_planes(img);
  std::vector<std::pair<std::string, const std::vector<float>*>> channels;
  for (const auto& [name, plane] : planes) channels.emplace_back(name, &plane);
  write_exr_channels(path, img.width, img.height, channels, img.epipole);
}

namespace {

// Writes `bytes` to `path`, checking every write and the close (a full disk fails here, not silently).
void write_bytes(const std::string& path, std::string_view bytes) {
  std::ofstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error(std::strerror(errno));
  f.write(bytes.data(), std::streamsize(bytes.size()));
  f.flush();
  if (!f) throw std::runtime_error(fmt::format("write failed: {}", std::strerror(errno)));
  f.close();
  if (!f) throw std::runtime_error(fmt::format("close failed: {}", std::strerror(errno)));
}

}  // namespace

void write_png_rgb8(const std::string& path, int width, int height, const std::vector<uint32_t>& rgba) {
  std::vector<uint8_t> rgb(rgba.size() * 3);
  for (size_t p = 0; p < rgba.size(); ++p)
    for (int c = 0; c < 3; ++c) rgb[p * 3 + size_t(c)] = uint8_t(rgba[p] >> (8 * c));
  // Encoded in memory: stb's own file writer does not check its writes.
  std::string png;
  auto append = [](void* ctx, void* data, int size) {
    static_cast<std::string*>(ctx)->append(static_cast<char*>(data), size_t(size));
  };
  if (!stbi_write_png_to_func(append, &png, width, height, 3, rgb.data(), width * 3))
    throw Error(fmt::format("cannot write {}: the PNG encoder failed", path));
  atomic_write(path, [&](const std::string& tmp) { write_bytes(tmp, png); });
}

void write_png(const std::string& path, const Image& img) {
  write_png_rgb8(path, img.width, img.height, img.ldr);
}

std::vector<uint32_t> preview_srgb8(const std::vector<float>& rgb, float exposure,
                                    const std::string& tonemap) {
  const uint32_t op = tonemap_op(tonemap);
  const float scale = std::exp2(exposure);
  std::vector<uint32_t> px(rgb.size() / 3);
  for (size_t p = 0; p < px.size(); ++p)
    px[p] =
        glsl::pack_srgb8(glsl::tonemap(glm::vec3(rgb[p * 3], rgb[p * 3 + 1], rgb[p * 3 + 2]) * scale, op));
  return px;
}

void write_text(const std::string& path, const std::string& text) {
  atomic_write(path, [&](const std::string& tmp) { write_bytes(tmp, text); });
}

void write_json(const std::string& path, const nlohmann::json& j) {
  write_text(path, j.dump(2) + "\n");
}

void ensure_writable_dir(const std::string& dir) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec)
    throw Error(
        fmt::format("cannot create output directory {}: {}; choose a writable --out", dir, ec.message()));
  fs::path probe = fs::path(dir) / fmt::format(".haze-write-test{}", getpid());
  std::ofstream f(probe);
  if (!f) throw Error(fmt::format("output directory {} is not writable; choose a writable --out", dir));
  f.close();
  fs::remove(probe, ec);
}

namespace {

// ".NAME.tmp<pid>" (temp_path_for) of a process that has ended: a run that was killed.
bool stale_temporary(const fs::path& p) {
  const std::string n = p.filename().string();
  const size_t tmp = n.rfind(".tmp");
  if (n.empty() || n[0] != '.' || tmp == std::string::npos || tmp + 4 >= n.size()) return false;
  const std::string digits = n.substr(tmp + 4);
  if (digits.find_first_not_of("0123456789") != std::string::npos || digits.size() > 9) return false;
  const pid_t pid = pid_t(std::stol(digits));
  return pid != getpid() && ::kill(pid, 0) != 0 && errno == ESRCH;
}

}  // namespace

OutputSet::OutputSet(std::string dir) : dir_(std::move(dir)) {
  ensure_writable_dir(dir_);
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir_, ec))
    if (e.is_regular_file(ec) && stale_temporary(e.path())) fs::remove(e.path(), ec);
}

OutputSet::~OutputSet() {
  if (committed_) return;
  std::error_code ec;
  for (const auto& [tmp, target] : staged_) fs::remove(tmp, ec);
}

void OutputSet::check(const std::string& name) const {
  const std::string target = (fs::path(dir_) / name).string();
  std::error_code ec;
  if (fs::is_directory(target, ec))
    throw Error(
        fmt::format("cannot write {}: it is a directory; move it away or choose another --out", target));
}

std::string OutputSet::stage(const std::string& name) {
  check(name);
  const std::string target = (fs::path(dir_) / name).string();
  staged_.emplace_back(temp_path_for(target), target);
  return staged_.back().first;
}

void OutputSet::commit() {
  for (const auto& [tmp, target] : staged_) {
    std::error_code ec;
    fs::rename(tmp, target, ec);
    if (ec) throw Error(fmt::format("cannot write {}: {}", target, ec.message()));
  }
  committed_ = true;
}

const std::vector<float>& ExrImage::channel(const std::string& name) const {
  for (size_t i = 0; i < channels.size(); ++i)
    if (channels[i] == name) return data[i];
  throw Error(fmt::format("EXR has no channel '{}'", name));
}

ExrImage read_exr(const std::string& path) {
  if (!fs::exists(path)) throw Error(fmt::format("cannot open {}: no such file", path));
  try {
    Imf::InputFile file(path.c_str());
    auto dw = file.header().dataWindow();
    ExrImage img;
    img.width = dw.max.x - dw.min.x + 1;
    img.height = dw.max.y - dw.min.y + 1;
    if (const auto* e = file.header().findTypedAttribute<Imf::V3fAttribute>(kEpipoleAttribute)) {
      const Imath::V3f v = e->value();
      img.epipole = glm::vec3(v.x, v.y, v.z);
    }
    Imf::FrameBuffer fb;
    for (auto it = file.header().channels().begin(); it != file.header().channels().end(); ++it)
      img.channels.push_back(it.name());
    img.data.resize(img.channels.size());
    for (size_t i = 0; i < img.channels.size(); ++i) {
      img.data[i].resize(size_t(img.width) * img.height);
      char* base = reinterpret_cast<char*>(img.data[i].data()) -
                   (size_t(dw.min.x) + size_t(dw.min.y) * img.width) * sizeof(float);
      fb.insert(img.channels[i], Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * img.width));
    }
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    return img;
  } catch (const std::exception& e) {
    throw Error(fmt::format("cannot read {}: {}", path, e.what()));
  }
}

}  // namespace haze::render
