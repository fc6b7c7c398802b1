#pragma once
// Per-pixel data as separate vec4 layers, one storage buffer each, so that no buffer of a frame outgrows
// the device's maxStorageBufferRange (128 MiB on lavapipe: 16 bytes a pixel reach 8.4 Mpixel, 3840x2160
// included). On the host the layers are seen side by side: pixel p's float 4*l + c is component c of
// layer l, so offsets such as ACC_T = 4 * layer + 3 name one float of an interleaved download.

#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <vector>

#include "gpu/buffer.hpp"
#include "gpu/kernel.hpp"

namespace haze::gpu {

class Context;

class PixelLayers : public DeviceData {
 public:
  PixelLayers() = default;
  // One buffer per name ("acc_l"), 16 bytes a pixel, named "<label> <name>" in the ledger. Names in `absent`
  // keep their place in the host layout (a download reads them as zeros) but have no buffer: a kernel that
  // declares these layers does not see them (no BINDING_<name>), and the scene pays nothing for them.
  PixelLayers(Context& ctx, const std::string& label, const std::string& category, uint64_t pixels,
              std::vector<std::string> names, const std::vector<std::string>& absent = {});

  uint64_t pixels() const { return pixels_; }
  size_t count() const { return layers_.size(); }
  uint32_t stride() const { return uint32_t(4 * layers_.size()); }  // floats per pixel on the host
  bool valid() const { return !layers_.empty(); }
  const Buffer& operator[](size_t i) const { return layers_[i]; }
  Buffer& operator[](size_t i) { return layers_[i]; }
  const Buffer& layer(const std::string& name) const;
  const std::vector<std::string>& names() const { return names_; }
  bool has(const std::string& name) const;  // listed and not absent

  // Every present layer as a buffer of pixels x 16 bytes.
  void declare(KernelDecl& k) const override;
  void bind(Bindings& b) const override;

  std::vector<float> download() const;                 // stride() floats per pixel
  void upload(const std::vector<float>& interleaved);  // stride() floats per pixel
  void fill_zero();
  void fill_zero(VkCommandBuffer cmd);
  void copy_to(VkCommandBuffer cmd, PixelLayers& dst) const;  // same layers (and absent ones) and size

 private:
  uint64_t pixels_ = 0;
  std::vector<std::string> names_;
  std::vector<Buffer> layers_;
};

}  // namespace haze::gpu
