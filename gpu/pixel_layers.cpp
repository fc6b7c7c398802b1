#include "gpu/pixel_layers.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/pipeline.hpp"

namespace haze::gpu {

PixelLayers::PixelLayers(Context& ctx, const std::string& label, const std::string& category, uint64_t pixels,
                         std::vector<std::string> names, const std::vector<std::string>& absent)
    : pixels_(pixels), names_(std::move(names)) {
  for (const auto& n : names_) {
    if (std::find(absent.begin(), absent.end(), n) != absent.end())
      layers_.emplace_back();
    else
      layers_.emplace_back(ctx, fmt::format("{} {}", label, n), category, pixels * 16, "4 x f32 per pixel");
  }
}

bool PixelLayers::has(const std::string& name) const {
  for (size_t i = 0; i < names_.size(); ++i)
    if (names_[i] == name) return layers_[i].valid();
  return false;
}

const Buffer& PixelLayers::layer(const std::string& name) const {
  for (size_t i = 0; i < names_.size(); ++i)
    if (names_[i] == name && layers_[i].valid()) return layers_[i];
  throw Error(fmt::format("no pixel layer '{}'", name));
}

void PixelLayers::declare(KernelDecl& k) const {
  for (size_t i = 0; i < names_.size(); ++i)
    if (layers_[i].valid()) k.buffer(names_[i], pixels_ * 16, 16);
}

void PixelLayers::bind(Bindings& b) const {
  for (size_t i = 0; i < names_.size(); ++i)
    if (layers_[i].valid()) b.set(names_[i], layers_[i]);
}

std::vector<float> PixelLayers::download() const {
  const size_t L = layers_.size();
  std::vector<float> out(size_t(pixels_) * 4 * L, 0.f);
  for (size_t l = 0; l < L; ++l) {
    if (!layers_[l].valid()) continue;
    std::vector<float> v = layers_[l].download_vector<float>();
    for (size_t p = 0; p < pixels_; ++p)
      for (size_t c = 0; c < 4; ++c) out[(p * L + l) * 4 + c] = v[p * 4 + c];
  }
  return out;
}

void PixelLayers::upload(const std::vector<float>& interleaved) {
  const size_t L = layers_.size();
  if (interleaved.size() != size_t(pixels_) * 4 * L)
    throw Error(fmt::format("pixel layers upload: {} floats for {} pixels x {} layers x 4",
                            interleaved.size(), pixels_, L));
  std::vector<float> v(size_t(pixels_) * 4);
  for (size_t l = 0; l < L; ++l) {
    if (!layers_[l].valid()) continue;
    for (size_t p = 0; p < pixels_; ++p)
      for (size_t c = 0; c < 4; ++c) v[p * 4 + c] = interleaved[(p * L + l) * 4 + c];
    layers_[l].upload(v);
  }
}

void PixelLayers::fill_zero() {
  for (auto& b : layers_)
    if (b.valid()) b.fill_zero();
}

void PixelLayers::fill_zero(VkCommandBuffer cmd) {
  for (auto& b : layers_)
    if (b.valid()) b.fill_zero(cmd);
}

void PixelLayers::copy_to(VkCommandBuffer cmd, PixelLayers& dst) const {
  if (dst.layers_.size() != layers_.size() || dst.pixels_ != pixels_)
    throw Error(fmt::format("pixel layers copy: {} layers of {} pixels into {} of {}", layers_.size(),
                            pixels_, dst.layers_.size(), dst.pixels_));
  for (size_t l = 0; l < layers_.size(); ++l) {
    if (layers_[l].valid() != dst.layers_[l].valid())
      throw Error(fmt::format("pixel layers copy: layer {} is present on one side only", l));
    if (layers_[l].valid()) copy_buffer(cmd, layers_[l], dst.layers_[l]);
  }
}

}  // namespace haze::gpu
