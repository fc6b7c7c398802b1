// Dear ImGui on the window (Debian's libimgui-dev 1.86: its GLFW and Vulkan backends). The frame's image is
// copied into the swapchain image first; the UI's render pass then loads it, draws on top and leaves the
// image ready to present.
#pragma once

#include <vulkan/vulkan.h>

#include <vector>

namespace haze::gpu {
class Context;
class Swapchain;
}  // namespace haze::gpu

namespace haze::view {

class Window;

class Ui {
 public:
  // `frames` in flight: ImGui's vertex buffers rotate over more than that many frames.
  Ui(gpu::Context& ctx, Window& window, const gpu::Swapchain& swapchain, uint32_t frames);
  ~Ui();
  Ui(const Ui&) = delete;
  Ui& operator=(const Ui&) = delete;

  // After the swapchain was made anew (its images and size changed).
  void recreate(const gpu::Swapchain& swapchain);
  // Starts the UI's frame (input, display size); widgets are drawn between this and record().
  void new_frame();
  // Records the render pass on swapchain image `image` (in TRANSFER_DST_OPTIMAL layout, holding the frame):
  // the UI when `draw`, else nothing on top. Leaves the image in PRESENT_SRC_KHR.
  void record(VkCommandBuffer cmd, uint32_t image, bool draw);

 private:
  void create_framebuffers(const gpu::Swapchain& swapchain);
  void destroy_framebuffers() noexcept;

  gpu::Context& ctx_;
  VkRenderPass render_pass_ = VK_NULL_HANDLE;
  VkDescriptorPool pool_ = VK_NULL_HANDLE;
  std::vector<VkFramebuffer> framebuffers_;
  VkExtent2D extent_{0, 0};
};

}  // namespace haze::view
