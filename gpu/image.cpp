#include "gpu/image.hpp"

#include <fmt/format.h>

#include <utility>

#include "gpu/buffer.hpp"
#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/vk_struct.hpp"

namespace haze::gpu {
namespace {

struct FormatInfo {
  VkFormat format;
  const char* name;
  uint32_t bytes;
};

constexpr FormatInfo kFormats[] = {
    {VK_FORMAT_R32G32B32A32_SFLOAT, "RGBA32F", 16},
    {VK_FORMAT_R16G16B16A16_SFLOAT, "RGBA16F", 8},
    {VK_FORMAT_R32G32_SFLOAT, "RG32F", 8},
    {VK_FORMAT_R16G16_SFLOAT, "RG16F", 4},
    {VK_FORMAT_R32_SFLOAT, "R32F", 4},
    {VK_FORMAT_R16_SFLOAT, "R16F", 2},
    {VK_FORMAT_R32_UINT, "R32UI", 4},
    {VK_FORMAT_R32_SINT, "R32I", 4},
    {VK_FORMAT_R8G8B8A8_UNORM, "RGBA8", 4},
    // Rarely storage-capable: listed so that the device check, not this table, explains the refusal.
    {VK_FORMAT_R8G8B8A8_SRGB, "RGBA8_SRGB", 4},
    {VK_FORMAT_R32G32B32_SFLOAT, "RGB32F", 12},
    {VK_FORMAT_B10G11R11_UFLOAT_PACK32, "R11G11B10F", 4},
};

const FormatInfo* find_format(VkFormat f) {
  for (const auto& info : kFormats)
    if (info.format == f) return &info;
  return nullptr;
}

std::string known_formats() {
  std::string s;
  for (const auto& info : kFormats) s += (s.empty() ? "" : ", ") + std::string(info.name);
  return s;
}

constexpr VkImageSubresourceRange kWholeImage{VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
constexpr VkPipelineStageFlags kUseStages =
    VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT;
constexpr VkAccessFlags kUseAccess = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
                                     VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;

VkBufferImageCopy whole_copy(uint32_t width, uint32_t height) {
  VkBufferImageCopy region{};
  region.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  region.imageExtent = {width, height, 1};  // bufferRowLength 0: rows tightly packed
  return region;
}

// Transfers run in the TRANSFER_*_OPTIMAL layouts (validation flags copies in GENERAL as slow) and leave the
// image in GENERAL again, ordered against every compute or transfer use before and after.
void transfer_layout(VkCommandBuffer cmd, VkImage image, VkImageLayout layout, bool into) {
  constexpr VkPipelineStageFlags kTransferStage = VK_PIPELINE_STAGE_TRANSFER_BIT;
  VkAccessFlags transfer = layout == VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL ? VK_ACCESS_TRANSFER_WRITE_BIT
                                                                          : VK_ACCESS_TRANSFER_READ_BIT;
  auto b = vk_struct<VkImageMemoryBarrier>(VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER);
  b.srcAccessMask = into ? kUseAccess : transfer;
  b.dstAccessMask = into ? transfer : kUseAccess;
  b.oldLayout = into ? VK_IMAGE_LAYOUT_GENERAL : layout;
  b.newLayout = into ? layout : VK_IMAGE_LAYOUT_GENERAL;
  b.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  b.image = image;
  b.subresourceRange = kWholeImage;
  vkCmdPipelineBarrier(cmd, into ? kUseStages : kTransferStage, into ? kTransferStage : kUseStages, 0, 0,
                       nullptr, 0, nullptr, 1, &b);
}

}  // namespace

std::string image_format_name(VkFormat format) {
  const FormatInfo* info = find_format(format);
  return info ? info->name : fmt::format("VkFormat({})", static_cast<int>(format));
}

uint32_t image_format_bytes(VkFormat format) {
  const FormatInfo* info = find_format(format);
  return info ? info->bytes : 0;
}

Image::Image(Context& ctx, std::string name, std::string category, uint32_t width, uint32_t height,
             VkFormat format)
    : ctx_(&ctx),
      width_(width),
      height_(height),
      format_(format),
      name_(std::move(name)),
      category_(std::move(category)) {
  try {
    create();
  } catch (...) {
    release();
    throw;
  }
}

std::string Image::describe() const {
  return fmt::format("{} {}x{}", format_name(), width_, height_);
}

void Image::create() {
  Context& ctx = *ctx_;
  if (!find_format(format_))
    throw Error(fmt::format("image '{}': format {} is not one gpu::Image supports ({})", name_, format_name(),
                            known_formats()));
  if (width_ == 0 || height_ == 0) throw Error(fmt::format("image '{}' ({}) is empty", name_, describe()));
  const auto too_big = [&](const char* limit, uint64_t w, uint64_t h) {
    return Error(fmt::format("image '{}' ({}, category {}) is larger than this device's {} ({}x{})", name_,
                             describe(), category_, limit, w, h));
  };
  uint32_t max_dim = ctx.limits().maxImageDimension2D;
  if (width_ > max_dim || height_ > max_dim) throw too_big("maxImageDimension2D", max_dim, max_dim);

  // Format features first: they say which use is missing, where the image-format query only says no.
  VkFormatProperties fp;
  vkGetPhysicalDeviceFormatProperties(ctx.physical(), format_, &fp);
  struct Need {
    VkFormatFeatureFlags bit;
    const char* use;
  };
  for (Need need : {Need{VK_FORMAT_FEATURE_STORAGE_IMAGE_BIT, "a storage image"},
                    Need{VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT, "a sampled image"},
                    Need{VK_FORMAT_FEATURE_TRANSFER_SRC_BIT, "a transfer source"},
                    Need{VK_FORMAT_FEATURE_TRANSFER_DST_BIT, "a transfer destination"}})
    if (!(fp.optimalTilingFeatures & need.bit))
      throw Error(fmt::format("image '{}' ({}): {} cannot use format {} as {} (optimal tiling)", name_,
                              describe(), ctx.device_name(), format_name(), need.use));

  constexpr VkImageUsageFlags kUsage = VK_IMAGE_USAGE_STORAGE_BIT | VK_IMAGE_USAGE_SAMPLED_BIT |
                                       VK_IMAGE_USAGE_TRANSFER_SRC_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
  VkImageFormatProperties ifp;
  VkResult r = vkGetPhysicalDeviceImageFormatProperties(ctx.physical(), format_, VK_IMAGE_TYPE_2D,
                                                        VK_IMAGE_TILING_OPTIMAL, kUsage, 0, &ifp);
  if (r == VK_ERROR_FORMAT_NOT_SUPPORTED)
    throw Error(fmt::format("image '{}' ({}): {} cannot create {} storage images", name_, describe(),
                            ctx.device_name(), format_name()));
  vk_check(r, fmt::format("vkGetPhysicalDeviceImageFormatProperties('{}')", name_));
  if (width_ > ifp.maxExtent.width || height_ > ifp.maxExtent.height)
    throw too_big("maximum extent for this format", ifp.maxExtent.width, ifp.maxExtent.height);

  const auto oom = [&] {
    return fmt::format("out of device memory allocating '{}' ({}, {}, category {})", name_, describe(),
                       format_bytes(size()), category_);
  };
  auto info = vk_struct<VkImageCreateInfo>(VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO);
  info.imageType = VK_IMAGE_TYPE_2D;
  info.format = format_;
  info.extent = {width_, height_, 1};
  info.mipLevels = 1;
  info.arrayLayers = 1;
  info.samples = VK_SAMPLE_COUNT_1_BIT;
  info.tiling = VK_IMAGE_TILING_OPTIMAL;
  info.usage = kUsage;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  info.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  r = vkCreateImage(ctx.device(), &info, nullptr, &image_);
  vk_check_alloc(r, fmt::format("vkCreateImage('{}')", name_), oom);

  VkMemoryRequirements req;
  vkGetImageMemoryRequirements(ctx.device(), image_, &req);
  if (ctx.max_allocation_size() && req.size > ctx.max_allocation_size())
    throw Error(fmt::format(
        "image '{}' ({}, {}, category {}) is larger than this device's "
        "maxMemoryAllocationSize ({})",
        name_, describe(), format_bytes(req.size), category_, format_bytes(ctx.max_allocation_size())));
  // Device-local, preferably not host-visible: the small BAR heap of discrete GPUs stays free, and optimal
  // tiling is opaque to the host anyway.
  const auto& mp = ctx.memory_properties();
  constexpr VkMemoryPropertyFlags kLocal = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
  constexpr VkMemoryPropertyFlags kHost = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT;
  int type = -1;
  for (auto [required, forbidden] : {std::pair{kLocal, kHost}, std::pair{kLocal, 0u}, std::pair{0u, 0u}}) {
    for (uint32_t i = 0; i < mp.memoryTypeCount && type < 0; ++i) {
      VkMemoryPropertyFlags f = mp.memoryTypes[i].propertyFlags;
      if ((req.memoryTypeBits & (1u << i)) && (f & required) == required && !(f & forbidden))
        type = static_cast<int>(i);
    }
    if (type >= 0) break;
  }
  if (type < 0) throw Error(fmt::format("no memory type can hold image '{}'", name_));

  auto ainfo = vk_struct<VkMemoryAllocateInfo>(VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO);
  ainfo.allocationSize = req.size;
  ainfo.memoryTypeIndex = static_cast<uint32_t>(type);
  r = vkAllocateMemory(ctx.device(), &ainfo, nullptr, &memory_);
  vk_check_alloc(r, fmt::format("vkAllocateMemory('{}')", name_), oom);
  r = vkBindImageMemory(ctx.device(), image_, memory_, 0);
  vk_check_alloc(r, fmt::format("vkBindImageMemory('{}')", name_), oom);
  allocated_ = req.size;

  auto vinfo = vk_struct<VkImageViewCreateInfo>(VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO);
  vinfo.image = image_;
  vinfo.viewType = VK_IMAGE_VIEW_TYPE_2D;
  vinfo.format = format_;
  vinfo.subresourceRange = kWholeImage;
  r = vkCreateImageView(ctx.device(), &vinfo, nullptr, &view_);
  vk_check_alloc(r, fmt::format("vkCreateImageView('{}')", name_), oom);
  ctx.set_object_name(VK_OBJECT_TYPE_IMAGE, reinterpret_cast<uint64_t>(image_), name_);
  ctx.set_object_name(VK_OBJECT_TYPE_IMAGE_VIEW, reinterpret_cast<uint64_t>(view_), name_);
  ledger_id_ = ctx.ledger().add({name_, category_, describe(), allocated_, size()});

  // GENERAL between calls: dispatches and clear(cmd) use it as is, so callers never track layouts.
  ctx.submit_and_wait([&](VkCommandBuffer cmd) {
    auto b = vk_struct<VkImageMemoryBarrier>(VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER);
    b.srcAccessMask = 0;
    b.dstAccessMask = kUseAccess;
    b.oldLayout = VK_IMAGE_LAYOUT_UNDEFINED;
    b.newLayout = VK_IMAGE_LAYOUT_GENERAL;
    b.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    b.image = image_;
    b.subresourceRange = kWholeImage;
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, kUseStages, 0, 0, nullptr, 0, nullptr, 1,
                         &b);
  });
}

void Image::release() noexcept {
  if (!ctx_) return;
  if (image_) {
    try {
      ctx_->wait_in_flight();  // a frame in flight may still use it
    } catch (...) {            // device lost: nothing runs any more
    }
  }
  if (ledger_id_) ctx_->ledger().remove(ledger_id_);
  if (view_) vkDestroyImageView(ctx_->device(), view_, nullptr);
  if (image_) vkDestroyImage(ctx_->device(), image_, nullptr);
  if (memory_) vkFreeMemory(ctx_->device(), memory_, nullptr);
  ctx_ = nullptr;
  image_ = VK_NULL_HANDLE;
  view_ = VK_NULL_HANDLE;
  memory_ = VK_NULL_HANDLE;
  ledger_id_ = 0;
}

Image::~Image() {
  release();
}

Image::Image(Image&& o) noexcept
    : ctx_(std::exchange(o.ctx_, nullptr)),
      image_(std::exchange(o.image_, VK_NULL_HANDLE)),
      view_(std::exchange(o.view_, VK_NULL_HANDLE)),
      memory_(std::exchange(o.memory_, VK_NULL_HANDLE)),
      width_(std::exchange(o.width_, 0)),
      height_(std::exchange(o.height_, 0)),
      format_(std::exchange(o.format_, VK_FORMAT_UNDEFINED)),
      allocated_(std::exchange(o.allocated_, 0)),
      ledger_id_(std::exchange(o.ledger_id_, 0)),
      name_(std::move(o.name_)),
      category_(std::move(o.category_)) {}

Image& Image::operator=(Image&& o) noexcept {
  if (this != &o) {
    release();
    ctx_ = std::exchange(o.ctx_, nullptr);
    image_ = std::exchange(o.image_, VK_NULL_HANDLE);
    view_ = std::exchange(o.view_, VK_NULL_HANDLE);
    memory_ = std::exchange(o.memory_, VK_NULL_HANDLE);
    width_ = std::exchange(o.width_, 0);
    height_ = std::exchange(o.height_, 0);
    format_ = std::exchange(o.format_, VK_FORMAT_UNDEFINED);
    allocated_ = std::exchange(o.allocated_, 0);
    ledger_id_ = std::exchange(o.ledger_id_, 0);
    name_ = std::move(o.name_);
    category_ = std::move(o.category_);
  }
  return *this;
}

void Image::check_transfer(const char* op, uint64_t bytes) const {
  if (!valid()) throw Error(fmt::format("{} on an empty gpu::Image", op));
  if (bytes != size())
    throw Error(fmt::format("{} of {} bytes for image '{}' ({}): whole images only, {} bytes tightly packed",
                            op, bytes, name_, describe(), size()));
}

void Image::upload(const void* data, uint64_t bytes) {
  check_transfer("upload", bytes);
  Buffer staging(*ctx_, "staging for '" + name_ + "'", "staging", bytes, describe(), Buffer::Kind::Staging);
  staging.upload(data, bytes, 0);
  ctx_->submit_and_wait([&](VkCommandBuffer cmd) {
    VkBufferImageCopy region = whole_copy(width_, height_);
    transfer_layout(cmd, image_, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, true);
    vkCmdCopyBufferToImage(cmd, staging.handle(), image_, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &region);
    transfer_layout(cmd, image_, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, false);
  });
}

void Image::download(void* data, uint64_t bytes) const {
  check_transfer("download", bytes);
  Buffer staging(*ctx_, "staging for '" + name_ + "'", "staging", bytes, describe(), Buffer::Kind::Staging);
  ctx_->submit_and_wait([&](VkCommandBuffer cmd) {
    VkBufferImageCopy region = whole_copy(width_, height_);
    transfer_layout(cmd, image_, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, true);
    vkCmdCopyImageToBuffer(cmd, image_, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, staging.handle(), 1, &region);
    transfer_layout(cmd, image_, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, false);
  });
  staging.download(data, bytes, 0);
}

void Image::clear() {
  if (!valid()) throw Error("clear on an empty gpu::Image");
  ctx_->submit_and_wait([&](VkCommandBuffer cmd) { clear(cmd); });
}

void Image::clear(VkCommandBuffer cmd) {
  if (!valid()) throw Error("clear on an empty gpu::Image");
  VkClearColorValue zero{};  // all-zero bits: 0 for float, unorm and integer formats alike
  vkCmdClearColorImage(cmd, image_, VK_IMAGE_LAYOUT_GENERAL, &zero, 1, &kWholeImage);
}

}  // namespace haze::gpu
