#include "gpu/swapchain.hpp"

#include <fmt/format.h>

#include <algorithm>

#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/vk_struct.hpp"

namespace haze::gpu {

Swapchain::Swapchain(Context& ctx, VkSurfaceKHR surface, uint32_t width, uint32_t height)
    : ctx_(ctx), surface_(surface) {
  VkBool32 supported = VK_FALSE;
  HAZE_VK(vkGetPhysicalDeviceSurfaceSupportKHR(ctx.physical(), ctx.queue_family(), surface, &supported));
  if (!supported)
    throw Error(
        fmt::format("'{}' cannot present to this window from its queue; pick another device with --device",
                    ctx.device_name()));
  uint32_t n = 0;
  HAZE_VK(vkGetPhysicalDeviceSurfaceFormatsKHR(ctx.physical(), surface, &n, nullptr));
  std::vector<VkSurfaceFormatKHR> formats(n);
  HAZE_VK(vkGetPhysicalDeviceSurfaceFormatsKHR(ctx.physical(), surface, &n, formats.data()));
  if (formats.empty()) throw Error(fmt::format("'{}' offers no format for this window", ctx.device_name()));
  // UNORM, so that the 8-bit sRGB-encoded preview and the UI's colours reach the screen as they are.
  format_ = formats[0].format;
  color_space_ = formats[0].colorSpace;
  for (VkFormat want : {VK_FORMAT_B8G8R8A8_UNORM, VK_FORMAT_R8G8B8A8_UNORM})
    for (const auto& f : formats)
      if (f.format == want && f.colorSpace == VK_COLOR_SPACE_SRGB_NONLINEAR_KHR) {
        format_ = f.format;
        color_space_ = f.colorSpace;
        goto chosen;
      }
chosen:
  HAZE_VK(vkGetPhysicalDeviceSurfacePresentModesKHR(ctx.physical(), surface, &n, nullptr));
  std::vector<VkPresentModeKHR> modes(n);
  HAZE_VK(vkGetPhysicalDeviceSurfacePresentModesKHR(ctx.physical(), surface, &n, modes.data()));
  // Never blocks on a display refresh (the frame loop paces itself); FIFO is always there.
  mode_ = VK_PRESENT_MODE_FIFO_KHR;
  for (VkPresentModeKHR want : {VK_PRESENT_MODE_MAILBOX_KHR, VK_PRESENT_MODE_IMMEDIATE_KHR})
    if (std::find(modes.begin(), modes.end(), want) != modes.end()) {
      mode_ = want;
      break;
    }
  create(width, height);
}

Swapchain::~Swapchain() {
  if (ctx_.device()) vkDeviceWaitIdle(ctx_.device());
  destroy_views();
  if (swapchain_) vkDestroySwapchainKHR(ctx_.device(), swapchain_, nullptr);
}

void Swapchain::destroy_views() noexcept {
  for (VkImageView v : views_) vkDestroyImageView(ctx_.device(), v, nullptr);
  views_.clear();
  images_.clear();
}

void Swapchain::create(uint32_t width, uint32_t height) {
  VkSurfaceCapabilitiesKHR caps;
  HAZE_VK(vkGetPhysicalDeviceSurfaceCapabilitiesKHR(ctx_.physical(), surface_, &caps));
  if (caps.currentExtent.width != 0xFFFFFFFFu) {
    extent_ = caps.currentExtent;
  } else {
    extent_.width = std::clamp(width, caps.minImageExtent.width, caps.maxImageExtent.width);
    extent_.height = std::clamp(height, caps.minImageExtent.height, caps.maxImageExtent.height);
  }
  min_images_ = std::max(caps.minImageCount, 2u);
  uint32_t count = min_images_ + 1;
  if (caps.maxImageCount > 0) count = std::min(count, caps.maxImageCount);
  const VkImageUsageFlags need = VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
  if ((caps.supportedUsageFlags & need) != need)
    throw Error(
        fmt::format("'{}': this window's images cannot be drawn into and copied to", ctx_.device_name()));
  readable_ = (caps.supportedUsageFlags & VK_IMAGE_USAGE_TRANSFER_SRC_BIT) != 0;

  VkSwapchainKHR old = swapchain_;
  auto info = vk_struct<VkSwapchainCreateInfoKHR>(VK_STRUCTURE_TYPE_SWAPCHAIN_CREATE_INFO_KHR);
  info.surface = surface_;
  info.minImageCount = count;
  info.imageFormat = format_;
  info.imageColorSpace = color_space_;
  info.imageExtent = extent_;
  info.imageArrayLayers = 1;
  info.imageUsage = need | (readable_ ? VK_IMAGE_USAGE_TRANSFER_SRC_BIT : 0);
  info.imageSharingMode = VK_SHARING_MODE_EXCLUSIVE;
  info.preTransform = (caps.supportedTransforms & VK_SURFACE_TRANSFORM_IDENTITY_BIT_KHR)
                          ? VK_SURFACE_TRANSFORM_IDENTITY_BIT_KHR
                          : caps.currentTransform;
  info.compositeAlpha = VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR;
  if (!(caps.supportedCompositeAlpha & VK_COMPOSITE_ALPHA_OPAQUE_BIT_KHR))
    for (VkCompositeAlphaFlagBitsKHR a :
         {VK_COMPOSITE_ALPHA_INHERIT_BIT_KHR, VK_COMPOSITE_ALPHA_PRE_MULTIPLIED_BIT_KHR,
          VK_COMPOSITE_ALPHA_POST_MULTIPLIED_BIT_KHR})
      if (caps.supportedCompositeAlpha & a) {
        info.compositeAlpha = a;
        break;
      }
  info.presentMode = mode_;
  info.clipped = VK_TRUE;
  info.oldSwapchain = old;
  HAZE_VK(vkCreateSwapchainKHR(ctx_.device(), &info, nullptr, &swapchain_));
  if (old) vkDestroySwapchainKHR(ctx_.device(), old, nullptr);

  uint32_t n = 0;
  HAZE_VK(vkGetSwapchainImagesKHR(ctx_.device(), swapchain_, &n, nullptr));
  images_.resize(n);
  HAZE_VK(vkGetSwapchainImagesKHR(ctx_.device(), swapchain_, &n, images_.data()));
  for (uint32_t i = 0; i < n; ++i) {
    auto vinfo = vk_struct<VkImageViewCreateInfo>(VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO);
    vinfo.image = images_[i];
    vinfo.viewType = VK_IMAGE_VIEW_TYPE_2D;
    vinfo.format = format_;
    vinfo.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
    VkImageView v = VK_NULL_HANDLE;
    HAZE_VK(vkCreateImageView(ctx_.device(), &vinfo, nullptr, &v));
    views_.push_back(v);
  }
}

void Swapchain::recreate(uint32_t width, uint32_t height) {
  HAZE_VK(vkDeviceWaitIdle(ctx_.device()));
  destroy_views();
  create(width, height);
}

bool Swapchain::acquire(VkSemaphore acquired, uint32_t* index) {
  VkResult r = vkAcquireNextImageKHR(ctx_.device(), swapchain_, UINT64_MAX, acquired, VK_NULL_HANDLE, index);
  if (r == VK_ERROR_OUT_OF_DATE_KHR) return false;
  if (r != VK_SUBOPTIMAL_KHR) vk_check(r, "vkAcquireNextImageKHR");
  return true;
}

bool Swapchain::present(uint32_t index, VkSemaphore ready) {
  auto info = vk_struct<VkPresentInfoKHR>(VK_STRUCTURE_TYPE_PRESENT_INFO_KHR);
  info.waitSemaphoreCount = 1;
  info.pWaitSemaphores = &ready;
  info.swapchainCount = 1;
  info.pSwapchains = &swapchain_;
  info.pImageIndices = &index;
  VkResult r = ctx_.present(info);
  if (r == VK_ERROR_OUT_OF_DATE_KHR || r == VK_SUBOPTIMAL_KHR) return false;
  vk_check(r, "vkQueuePresentKHR");
  return true;
}

}  // namespace haze::gpu
