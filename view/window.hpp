// The viewer's window: GLFW on X11 (Xvfb for headless runs) and its Vulkan surface.
#pragma once

#include <vulkan/vulkan.h>

#include <glm/vec2.hpp>
#include <string>
#include <vector>

struct GLFWwindow;

namespace haze::view {

class Window {
 public:
  // Opens a window of width x height pixels. Without a display the error says how to get one (xvfb-run).
  Window(int width, int height, const std::string& title);
  ~Window();
  Window(const Window&) = delete;
  Window& operator=(const Window&) = delete;

  // The instance extensions its surface needs (VK_KHR_surface and the platform's).
  std::vector<std::string> instance_extensions() const;
  // Made once. destroy_surface() must run before the instance goes (the window outlives the context, which
  // needs its extensions).
  VkSurfaceKHR surface(VkInstance instance);
  void destroy_surface();

  GLFWwindow* handle() const { return window_; }
  bool should_close() const;
  void poll() const;
  glm::ivec2 framebuffer_size() const;

 private:
  GLFWwindow* window_ = nullptr;
  VkInstance instance_ = VK_NULL_HANDLE;
  VkSurfaceKHR surface_ = VK_NULL_HANDLE;
};

}  // namespace haze::view
