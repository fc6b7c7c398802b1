#include "gpu/buffer.hpp"

#include <fmt/format.h>

#include <cstring>
#include <utility>

#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/vk_struct.hpp"

namespace haze::gpu {
namespace {

struct TypeRule {
  VkMemoryPropertyFlags required, forbidden;
};

int find_type(const VkPhysicalDeviceMemoryProperties& mp, uint32_t bits,
              std::initializer_list<TypeRule> rules) {
  for (const auto& rule : rules)
    for (uint32_t i = 0; i < mp.memoryTypeCount; ++i) {
      VkMemoryPropertyFlags f = mp.memoryTypes[i].propertyFlags;
      if ((bits & (1u << i)) && (f & rule.required) == rule.required && !(f & rule.forbidden))
        return static_cast<int>(i);
    }
  return -1;
}

}  // namespace

Buffer::Buffer(Context& ctx, std::string name, std::string category, uint64_t bytes, std::string format)
    : Buffer(ctx, std::move(name), std::move(category), bytes, std::move(format), Kind::Storage) {}

Buffer::Buffer(Context& ctx, std::string name, std::string category, uint64_t bytes, std::string format,
               Kind kind)
    : ctx_(&ctx),
      size_(bytes),
      name_(std::move(name)),
      category_(std::move(category)),
      format_(std::move(format)) {
  try {
    create(kind);
  } catch (...) {
    release();
    throw;
  }
}

void Buffer::create(Kind kind) {
  Context& ctx = *ctx_;
  const auto oom = [&] {
    return fmt::format("out of device memory allocating '{}' ({}, category {})", name_, format_bytes(size_),
                       category_);
  };
  const auto too_big = [&](const char* limit, uint64_t value) {
    return Error(fmt::format("buffer '{}' ({}, category {}) is larger than this device's {} ({})", name_,
                             format_bytes(size_), category_, limit, format_bytes(value)));
  };
  if (ctx.max_allocation_size() && size_ > ctx.max_allocation_size())
    throw too_big("maxMemoryAllocationSize", ctx.max_allocation_size());
  if (ctx.max_buffer_size() && size_ > ctx.max_buffer_size())
    throw too_big("maxBufferSize", ctx.max_buffer_size());
  bool bda = ctx.features().buffer_device_address && kind == Kind::Storage;
  // Past maxStorageBufferRange a buffer can only be reached through its device address.
  if (kind == Kind::Storage && !bda && size_ > ctx.limits().maxStorageBufferRange)
    throw too_big("maxStorageBufferRange", ctx.limits().maxStorageBufferRange);

  auto info = vk_struct<VkBufferCreateInfo>(VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO);
  info.size = std::max<uint64_t>(4, (size_ + 3) & ~uint64_t{3});  // 4-multiple so fills reach every byte
  info.usage = kind == Kind::Staging ? VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT
                                     : VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_TRANSFER_SRC_BIT |
                                           VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  if (bda) info.usage |= VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  VkResult r = vkCreateBuffer(ctx.device(), &info, nullptr, &buffer_);
  vk_check_alloc(r, fmt::format("vkCreateBuffer('{}')", name_), oom);

  VkMemoryRequirements req;
  vkGetBufferMemoryRequirements(ctx.device(), buffer_, &req);
  const auto& mp = ctx.memory_properties();
  constexpr VkMemoryPropertyFlags kLocal = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
  constexpr VkMemoryPropertyFlags kHost = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT;
  constexpr VkMemoryPropertyFlags kCoherent = VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  constexpr VkMemoryPropertyFlags kCached = VK_MEMORY_PROPERTY_HOST_CACHED_BIT;
  int type = -1;
  if (kind == Kind::Staging) {
    type = find_type(mp, req.memoryTypeBits,
                     {{kHost | kCoherent | kCached, 0}, {kHost | kCoherent, 0}, {kHost, 0}});
  } else if (ctx.is_discrete()) {
    // Keep the small host-visible BAR heap of discrete GPUs free: big buffers go to plain VRAM.
    type = find_type(mp, req.memoryTypeBits, {{kLocal, kHost}, {kLocal, 0}, {0, 0}});
  } else {
    // Unified memory (integrated GPUs, lavapipe): host-visible device memory needs no staging copies.
    type = find_type(mp, req.memoryTypeBits,
                     {{kLocal | kHost | kCoherent, 0}, {kLocal | kHost, 0}, {kLocal, 0}, {0, 0}});
  }
  if (type < 0) throw Error(fmt::format("no memory type can hold buffer '{}'", name_));
  VkMemoryPropertyFlags flags = mp.memoryTypes[type].propertyFlags;

  auto aflags = vk_struct<VkMemoryAllocateFlagsInfo>(VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO);
  aflags.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
  auto ainfo =
      vk_struct<VkMemoryAllocateInfo>(VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, bda ? &aflags : nullptr);
  ainfo.allocationSize = req.size;
  ainfo.memoryTypeIndex = static_cast<uint32_t>(type);
  r = vkAllocateMemory(ctx.device(), &ainfo, nullptr, &memory_);
  vk_check_alloc(r, fmt::format("vkAllocateMemory('{}')", name_), oom);
  r = vkBindBufferMemory(ctx.device(), buffer_, memory_, 0);
  vk_check_alloc(r, fmt::format("vkBindBufferMemory('{}')", name_), oom);
  allocated_ = req.size;
  ctx.set_object_name(VK_OBJECT_TYPE_BUFFER, reinterpret_cast<uint64_t>(buffer_), name_);

  if ((flags & kHost) && (kind == Kind::Staging || !ctx.force_staging())) {
    r = vkMapMemory(ctx.device(), memory_, 0, VK_WHOLE_SIZE, 0, &mapped_);
    vk_check_alloc(r, fmt::format("vkMapMemory('{}')", name_), oom);
    coherent_ = (flags & kCoherent) != 0;
  }
  if (bda) {
    auto ai = vk_struct<VkBufferDeviceAddressInfo>(VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO);
    ai.buffer = buffer_;
    address_ = vkGetBufferDeviceAddress(ctx.device(), &ai);
  }
  ledger_id_ = ctx.ledger().add({name_, category_, format_, allocated_, size_});
}

Buffer Buffer::host_visible(Context& ctx, std::string name, std::string category, uint64_t bytes,
                            std::string format) {
  return Buffer(ctx, std::move(name), std::move(category), bytes, std::move(format), Kind::Staging);
}

void Buffer::release() noexcept {
  if (!ctx_) return;
  // A frame in flight may still use it.
  if (buffer_) {
    try {
      ctx_->wait_in_flight();
    } catch (...) {  // device lost: nothing runs any more
    }
  }
  if (ledger_id_) ctx_->ledger().remove(ledger_id_);
  if (mapped_) vkUnmapMemory(ctx_->device(), memory_);
  if (buffer_) vkDestroyBuffer(ctx_->device(), buffer_, nullptr);
  if (memory_) vkFreeMemory(ctx_->device(), memory_, nullptr);
  ctx_ = nullptr;
  buffer_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  mapped_ = nullptr;
  ledger_id_ = 0;
  address_ = 0;
}

Buffer::~Buffer() {
  release();
}

Buffer::Buffer(Buffer&& o) noexcept
    : ctx_(std::exchange(o.ctx_, nullptr)),
      buffer_(std::exchange(o.buffer_, VK_NULL_HANDLE)),
      memory_(std::exchange(o.memory_, VK_NULL_HANDLE)),
      mapped_(std::exchange(o.mapped_, nullptr)),
      coherent_(o.coherent_),
      size_(std::exchange(o.size_, 0)),
      allocated_(std::exchange(o.allocated_, 0)),
      ledger_id_(std::exchange(o.ledger_id_, 0)),
      address_(std::exchange(o.address_, 0)),
      name_(std::move(o.name_)),
      category_(std::move(o.category_)),
      format_(std::move(o.format_)) {}

Buffer& Buffer::operator=(Buffer&& o) noexcept {
  if (this != &o) {
    release();
    ctx_ = std::exchange(o.ctx_, nullptr);
    buffer_ = std::exchange(o.buffer_, VK_NULL_HANDLE);
    memory_ = std::exchange(o.memory_, VK_NULL_HANDLE);
    mapped_ = std::exchange(o.mapped_, nullptr);
    coherent_ = o.coherent_;
    size_ = std::exchange(o.size_, 0);
    allocated_ = std::exchange(o.allocated_, 0);
    ledger_id_ = std::exchange(o.ledger_id_, 0);
    address_ = std::exchange(o.address_, 0);
    name_ = std::move(o.name_);
    category_ = std::move(o.category_);
    format_ = std::move(o.format_);
  }
  return *this;
}

void Buffer::check_range(const char* op, uint64_t bytes, uint64_t offset) const {
  if (!valid()) throw Error(fmt::format("{} on an empty gpu::Buffer", op));
  if (offset > size_ || bytes > size_ - offset)
    throw Error(fmt::format("{} of {} bytes at offset {} is outside buffer '{}' ({} bytes)", op, bytes,
                            offset, name_, size_));
}

void Buffer::upload(const void* data, uint64_t bytes, uint64_t offset) {
  check_range("upload", bytes, offset);
  if (bytes == 0) return;
  if (mapped_) {
    ctx_->wait_in_flight();
    write_mapped(data, bytes, offset);
    return;
  }
  Buffer staging(*ctx_, "staging for '" + name_ + "'", "staging", bytes, format_, Kind::Staging);
  staging.write_mapped(data, bytes, 0);  // a new buffer: no frame uses it
  ctx_->submit_and_wait([&](VkCommandBuffer cmd) {
    VkBufferCopy region{0, offset, bytes};
    vkCmdCopyBuffer(cmd, staging.buffer_, buffer_, 1, &region);
  });
}

void Buffer::write_mapped(const void* data, uint64_t bytes, uint64_t offset) {
  std::memcpy(static_cast<char*>(mapped_) + offset, data, bytes);
  if (!coherent_) {
    auto range = vk_struct<VkMappedMemoryRange>(VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE);
    range.memory = memory_;
    range.size = VK_WHOLE_SIZE;
    HAZE_VK(vkFlushMappedMemoryRanges(ctx_->device(), 1, &range));
  }
}

void Buffer::download(void* data, uint64_t bytes, uint64_t offset) const {
  check_range("download", bytes, offset);
  if (bytes == 0) return;
  if (mapped_) {
    ctx_->wait_in_flight();
    read_mapped(data, bytes, offset);
    return;
  }
  Buffer staging(*ctx_, "staging for '" + name_ + "'", "staging", bytes, format_, Kind::Staging);
  ctx_->submit_and_wait([&](VkCommandBuffer cmd) {
    VkBufferCopy region{offset, 0, bytes};
    vkCmdCopyBuffer(cmd, buffer_, staging.buffer_, 1, &region);
  });
  staging.read_mapped(data, bytes, 0);
}

void Buffer::read_mapped(void* data, uint64_t bytes, uint64_t offset) const {
  check_range("read_mapped", bytes, offset);
  if (!mapped_) throw Error(fmt::format("read_mapped of buffer '{}', which is not host-mapped", name_));
  if (bytes == 0) return;
  {
    if (!coherent_) {
      auto range = vk_struct<VkMappedMemoryRange>(VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE);
      range.memory = memory_;
      range.size = VK_WHOLE_SIZE;
      HAZE_VK(vkInvalidateMappedMemoryRanges(ctx_->device(), 1, &range));
    }
    std::memcpy(data, static_cast<const char*>(mapped_) + offset, bytes);
  }
}

void Buffer::fill_zero() {
  if (!valid()) throw Error("fill_zero on an empty gpu::Buffer");
  ctx_->submit_and_wait([&](VkCommandBuffer cmd) { fill(cmd, 0); });
}

void Buffer::fill_zero(VkCommandBuffer cmd) {
  fill(cmd, 0);
}

void Buffer::fill(VkCommandBuffer cmd, uint32_t value) {
  if (!valid()) throw Error("fill on an empty gpu::Buffer");
  vkCmdFillBuffer(cmd, buffer_, 0, VK_WHOLE_SIZE, value);
}

VkDeviceAddress Buffer::device_address() const {
  if (!address_)
    throw Error(fmt::format(
        "buffer '{}' has no device address (bufferDeviceAddress unsupported or empty buffer)", name_));
  return address_;
}

void copy_buffer(VkCommandBuffer cmd, const Buffer& src, Buffer& dst, uint64_t bytes, uint64_t src_offset,
                 uint64_t dst_offset) {
  if (!src.valid() || !dst.valid()) throw Error("copy_buffer with an empty gpu::Buffer");
  if (bytes == UINT64_MAX) bytes = src_offset <= src.size() ? src.size() - src_offset : 0;
  if (src_offset > src.size() || bytes > src.size() - src_offset || dst_offset > dst.size() ||
      bytes > dst.size() - dst_offset)
    throw Error(fmt::format("copy of {} bytes from '{}' (+{}) to '{}' (+{}) is out of range", bytes,
                            src.name(), src_offset, dst.name(), dst_offset));
  if (bytes == 0) return;
  VkBufferCopy region{src_offset, dst_offset, bytes};
  vkCmdCopyBuffer(cmd, src.handle(), dst.handle(), 1, &region);
}

}  // namespace haze::gpu
