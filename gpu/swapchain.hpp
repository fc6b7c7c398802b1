#pragma once
// A window's swapchain on the context's queue: its images, acquire and present. The window and its
// VkSurfaceKHR belong to the caller (view/, through GLFW); the context must have been made with the
// window's extensions (ContextOptions::instance_extensions, device_extensions, graphics).

#include <vulkan/vulkan.h>

#include <cstdint>
#include <vector>

namespace haze::gpu {

class Context;

class Swapchain {
 public:
  // Checks that the context's queue can present to `surface`, else throws an Error naming the device.
  Swapchain(Context& ctx, VkSurfaceKHR surface, uint32_t width, uint32_t height);
  ~Swapchain();
  Swapchain(const Swapchain&) = delete;
  Swapchain& operator=(const Swapchain&) = delete;

  // Makes the swapchain anew at this size (a resized window, an out-of-date one). Waits for the device.
  void recreate(uint32_t width, uint32_t height);
  // The next image to draw into; `acquired` is signalled when it may be written. False: the swapchain is
  // out of date (recreate() and try again).
  bool acquire(VkSemaphore acquired, uint32_t* index);
  // Presents image `index` once `ready` is signalled. False: out of date or suboptimal (recreate()).
  bool present(uint32_t index, VkSemaphore ready);

  VkSwapchainKHR handle() const { return swapchain_; }
  VkFormat format() const { return format_; }
  VkExtent2D extent() const { return extent_; }
  uint32_t min_image_count() const { return min_images_; }
  uint32_t image_count() const { return uint32_t(images_.size()); }
  VkImage image(uint32_t i) const { return images_[i]; }
  VkImageView view(uint32_t i) const { return views_[i]; }
  // Whether images can be copied out (a screenshot of what the window shows).
  bool readable() const { return readable_; }
  VkPresentModeKHR present_mode() const { return mode_; }

 private:
  void create(uint32_t width, uint32_t height);
  void destroy_views() noexcept;

  Context& ctx_;
  VkSurfaceKHR surface_;
  VkSwapchainKHR swapchain_ = VK_NULL_HANDLE;
  VkFormat format_ = VK_FORMAT_UNDEFINED;
  VkColorSpaceKHR color_space_ = VK_COLOR_SPACE_SRGB_NONLINEAR_KHR;
  VkPresentModeKHR mode_ = VK_PRESENT_MODE_FIFO_KHR;
  VkExtent2D extent_{0, 0};
  uint32_t min_images_ = 2;
  bool readable_ = false;
  std::vector<VkImage> images_;
  std::vector<VkImageView> views_;
};

}  // namespace haze::gpu
