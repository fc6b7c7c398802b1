#pragma once
// 2D storage images: RAII, move-only, each one a line in the context's memory ledger.

#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

namespace haze::gpu {

class Context;

// Short name of a format gpu::Image knows ("RGBA16F"); "VkFormat(N)" for any other.
std::string image_format_name(VkFormat format);
// Bytes per pixel of a format gpu::Image knows; 0 for any other.
uint32_t image_format_bytes(VkFormat format);

// Usage STORAGE | SAMPLED | TRANSFER_SRC | TRANSFER_DST, optimal tiling, device-local memory, one mip level,
// one layer. In VK_IMAGE_LAYOUT_GENERAL from creation on, whenever callers record work on it (the constructor
// submits that transition, so do not create one inside a submit_and_wait callback). Known formats: RGBA32F,
// RGBA16F, RG32F, RG16F, R32F, R16F, R32UI, R32I, RGBA8 (UNORM), RGBA8_SRGB, RGB32F, R11G11B10F; the device
// must also support the format as a storage image, else the constructor throws an Error naming the image and
// the format.
class Image {
 public:
  Image() = default;
  Image(Context& ctx, std::string name, std::string category, uint32_t width, uint32_t height,
        VkFormat format);
  ~Image();
  Image(Image&& other) noexcept;
  Image& operator=(Image&& other) noexcept;
  Image(const Image&) = delete;
  Image& operator=(const Image&) = delete;

  // Blocking transfers of the whole image through a staging buffer ("staging" in the ledger while they run);
  // rows tightly packed, bytes == size(). The copy runs in a TRANSFER_*_OPTIMAL layout, GENERAL again after.
  void upload(const void* data, uint64_t bytes);
  void download(void* data, uint64_t bytes) const;
  void clear();                     // every texel to zero (vkCmdClearColorImage), submitted and waited for
  void clear(VkCommandBuffer cmd);  // recorded only; put a compute_barrier() before the readers

  VkImage handle() const { return image_; }
  VkImageView view() const { return view_; }
  uint32_t width() const { return width_; }
  uint32_t height() const { return height_; }
  VkFormat format() const { return format_; }
  std::string format_name() const { return image_format_name(format_); }
  uint32_t bytes_per_pixel() const { return image_format_bytes(format_); }
  uint64_t size() const { return uint64_t{width_} * height_ * bytes_per_pixel(); }  // tightly packed
  uint64_t allocated() const { return allocated_; }  // bytes of device memory behind it
  const std::string& name() const { return name_; }
  const std::string& category() const { return category_; }
  bool valid() const { return image_ != VK_NULL_HANDLE; }

  template <class T>
  void upload(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    upload(v.data(), v.size() * sizeof(T));
  }
  template <class T>
  std::vector<T> download_vector() const {  // size()/sizeof(T) elements
    static_assert(std::is_trivially_copyable_v<T>);
    std::vector<T> v(size() / sizeof(T));
    download(v.data(), v.size() * sizeof(T));
    return v;
  }

 private:
  void create();
  void release() noexcept;
  void check_transfer(const char* op, uint64_t bytes) const;
  std::string describe() const;  // "RGBA16F 640x360"

  Context* ctx_ = nullptr;
  VkImage image_ = VK_NULL_HANDLE;
  VkImageView view_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  uint32_t width_ = 0, height_ = 0;
  VkFormat format_ = VK_FORMAT_UNDEFINED;
  uint64_t allocated_ = 0, ledger_id_ = 0;
  std::string name_, category_;
};

}  // namespace haze::gpu
