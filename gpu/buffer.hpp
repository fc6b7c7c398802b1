#pragma once
// Storage buffers: RAII, move-only, each one a line in the context's memory ledger.

#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

namespace haze::gpu {

class Context;

// Usage STORAGE | TRANSFER_SRC | TRANSFER_DST (+ SHADER_DEVICE_ADDRESS where supported). Prefers DEVICE_LOCAL
// memory; when that is not HOST_VISIBLE, upload/download go through a temporary staging buffer.
// Zero-byte buffers allocate 4 bytes (Vulkan forbids 0) but size() and the ledger's 'requested' stay 0.
class Buffer {
 public:
  Buffer() = default;
  Buffer(Context& ctx, std::string name, std::string category, uint64_t bytes, std::string format = "bytes");
  ~Buffer();
  Buffer(Buffer&& other) noexcept;
  Buffer& operator=(Buffer&& other) noexcept;
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;

  // A host-visible buffer for transfers only (a frame's readback): mapped, never staged.
  static Buffer host_visible(Context& ctx, std::string name, std::string category, uint64_t bytes,
                             std::string format = "bytes");

  // Blocking transfers (each waits for the queue, and for the frames in flight: Context::wait_in_flight);
  // ranges are checked against size().
  void upload(const void* data, uint64_t bytes, uint64_t offset = 0);
  void download(void* data, uint64_t bytes, uint64_t offset = 0) const;
  // Reads a mapped buffer without waiting for anything: for a readback buffer whose frame is known to be
  // complete (gpu::FrameRing::on_complete) while later frames still run.
  void read_mapped(void* data, uint64_t bytes, uint64_t offset = 0) const;
  void fill_zero();                     // vkCmdFillBuffer, submitted and waited for
  void fill_zero(VkCommandBuffer cmd);  // recorded only; put a compute_barrier() before the readers
  void fill(VkCommandBuffer cmd, uint32_t value);

  VkBuffer handle() const { return buffer_; }
  uint64_t size() const { return size_; }            // bytes requested
  uint64_t allocated() const { return allocated_; }  // bytes of device memory behind it
  const std::string& name() const { return name_; }
  const std::string& category() const { return category_; }
  const std::string& format() const { return format_; }
  bool valid() const { return buffer_ != VK_NULL_HANDLE; }
  bool host_mapped() const { return mapped_ != nullptr; }  // transfers are plain memcpy
  VkDeviceAddress device_address() const;                  // throws where bufferDeviceAddress is unsupported

  template <class T>
  void upload(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    upload(v.data(), v.size() * sizeof(T));
  }
  template <class T>
  std::vector<T> download_vector() const {  // size()/sizeof(T) elements
    static_assert(std::is_trivially_copyable_v<T>);
    std::vector<T> v(size_ / sizeof(T));
    download(v.data(), v.size() * sizeof(T));
    return v;
  }

 private:
  friend class Image;  // stages its transfers through Kind::Staging buffers
  enum class Kind { Storage, Staging };
  Buffer(Context& ctx, std::string name, std::string category, uint64_t bytes, std::string format, Kind kind);
  void create(Kind kind);
  void release() noexcept;
  void check_range(const char* op, uint64_t bytes, uint64_t offset) const;
  void write_mapped(const void* data, uint64_t bytes, uint64_t offset);

  Context* ctx_ = nullptr;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  void* mapped_ = nullptr;
  bool coherent_ = true;
  uint64_t size_ = 0, allocated_ = 0, ledger_id_ = 0;
  VkDeviceAddress address_ = 0;
  std::string name_, category_, format_;
};

// Keeps `b` holding `data`: uploads it, reallocating only when the size changes (the ledger entry then
// changes too); empties `b` when `wanted` is false, so that an absent feature holds no memory.
template <class T>
void keep_uploaded(Context& ctx, Buffer& b, bool wanted, const std::string& name, const std::string& category,
                   const std::vector<T>& data, const std::string& format) {
  if (!wanted) {
    b = Buffer();
    return;
  }
  const uint64_t bytes = data.size() * sizeof(T);
  if (!b.valid() || b.size() != bytes) b = Buffer(ctx, name, category, bytes, format);
  b.upload(data);
}

// Records a buffer-to-buffer copy (bytes = UINT64_MAX: all of src); ranges are checked.
void copy_buffer(VkCommandBuffer cmd, const Buffer& src, Buffer& dst, uint64_t bytes = UINT64_MAX,
                 uint64_t src_offset = 0, uint64_t dst_offset = 0);

}  // namespace haze::gpu
