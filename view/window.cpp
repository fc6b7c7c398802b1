#include "view/window.hpp"

#define GLFW_INCLUDE_VULKAN
#include <GLFW/glfw3.h>
#include <fmt/format.h>

#include <cstdlib>
#include <stdexcept>

#include "gpu/error.hpp"

namespace haze::view {
namespace {

std::string glfw_error() {
  const char* what = nullptr;
  glfwGetError(&what);
  return what ? what : "unknown error";
}

}  // namespace

Window::Window(int width, int height, const std::string& title) {
  const char* display = std::getenv("DISPLAY");
  if (!display || !*display)
    throw std::runtime_error(
        "haze view needs an X display and $DISPLAY is not set; for a headless run use xvfb-run -a haze view "
        "...");
  glfwInitHint(GLFW_JOYSTICK_HAT_BUTTONS, GLFW_FALSE);
  if (!glfwInit()) throw std::runtime_error(fmt::format("cannot open display {}: {}", display, glfw_error()));
  if (!glfwVulkanSupported()) {
    glfwTerminate();
    throw std::runtime_error("GLFW finds no Vulkan loader for windows; run scripts/setup.sh");
  }
  glfwWindowHint(GLFW_CLIENT_API, GLFW_NO_API);
  glfwWindowHint(GLFW_RESIZABLE, GLFW_TRUE);
  window_ = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
  if (!window_) {
    const std::string e = glfw_error();
    glfwTerminate();
    throw std::runtime_error(
        fmt::format("cannot open a {}x{} window on display {}: {}", width, height, display, e));
  }
}

void Window::destroy_surface() {
  if (surface_) vkDestroySurfaceKHR(instance_, surface_, nullptr);
  surface_ = VK_NULL_HANDLE;
}

Window::~Window() {
  if (window_) glfwDestroyWindow(window_);
  glfwTerminate();
}

std::vector<std::string> Window::instance_extensions() const {
  uint32_t n = 0;
  const char** names = glfwGetRequiredInstanceExtensions(&n);
  std::vector<std::string> out;
  for (uint32_t i = 0; i < n; ++i) out.emplace_back(names[i]);
  return out;
}

VkSurfaceKHR Window::surface(VkInstance instance) {
  if (surface_) return surface_;
  VkResult r = glfwCreateWindowSurface(instance, window_, nullptr, &surface_);
  if (r != VK_SUCCESS)
    throw gpu::Error(fmt::format("cannot make a Vulkan surface for the window: {}", glfw_error()));
  instance_ = instance;
  return surface_;
}

bool Window::should_close() const {
  return glfwWindowShouldClose(window_);
}

void Window::poll() const {
  glfwPollEvents();
}

glm::ivec2 Window::framebuffer_size() const {
  int w = 0, h = 0;
  glfwGetFramebufferSize(window_, &w, &h);
  return {w, h};
}

}  // namespace haze::view
