#include "gpu/error.hpp"

#include <fmt/format.h>

namespace haze::gpu {

std::string result_name(VkResult r) {
  switch (r) {
#define HAZE_RESULT(x) \
  case x:              \
    return #x;
    HAZE_RESULT(VK_SUCCESS)
    HAZE_RESULT(VK_NOT_READY)
    HAZE_RESULT(VK_TIMEOUT)
    HAZE_RESULT(VK_EVENT_SET)
    HAZE_RESULT(VK_EVENT_RESET)
    HAZE_RESULT(VK_INCOMPLETE)
    HAZE_RESULT(VK_ERROR_OUT_OF_HOST_MEMORY)
    HAZE_RESULT(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    HAZE_RESULT(VK_ERROR_INITIALIZATION_FAILED)
    HAZE_RESULT(VK_ERROR_DEVICE_LOST)
    HAZE_RESULT(VK_ERROR_MEMORY_MAP_FAILED)
    HAZE_RESULT(VK_ERROR_LAYER_NOT_PRESENT)
    HAZE_RESULT(VK_ERROR_EXTENSION_NOT_PRESENT)
    HAZE_RESULT(VK_ERROR_FEATURE_NOT_PRESENT)
    HAZE_RESULT(VK_ERROR_INCOMPATIBLE_DRIVER)
    HAZE_RESULT(VK_ERROR_TOO_MANY_OBJECTS)
    HAZE_RESULT(VK_ERROR_FORMAT_NOT_SUPPORTED)
    HAZE_RESULT(VK_ERROR_FRAGMENTED_POOL)
    HAZE_RESULT(VK_ERROR_UNKNOWN)
    HAZE_RESULT(VK_ERROR_OUT_OF_POOL_MEMORY)
    HAZE_RESULT(VK_ERROR_INVALID_EXTERNAL_HANDLE)
    HAZE_RESULT(VK_ERROR_FRAGMENTATION)
    HAZE_RESULT(VK_ERROR_INVALID_OPAQUE_CAPTURE_ADDRESS)
    HAZE_RESULT(VK_PIPELINE_COMPILE_REQUIRED)
    HAZE_RESULT(VK_ERROR_SURFACE_LOST_KHR)
    HAZE_RESULT(VK_ERROR_NATIVE_WINDOW_IN_USE_KHR)
    HAZE_RESULT(VK_SUBOPTIMAL_KHR)
    HAZE_RESULT(VK_ERROR_OUT_OF_DATE_KHR)
    HAZE_RESULT(VK_ERROR_INCOMPATIBLE_DISPLAY_KHR)
    HAZE_RESULT(VK_ERROR_VALIDATION_FAILED_EXT)
    HAZE_RESULT(VK_ERROR_INVALID_SHADER_NV)
    HAZE_RESULT(VK_ERROR_INVALID_DRM_FORMAT_MODIFIER_PLANE_LAYOUT_EXT)
    HAZE_RESULT(VK_ERROR_NOT_PERMITTED_KHR)
    HAZE_RESULT(VK_THREAD_IDLE_KHR)
    HAZE_RESULT(VK_THREAD_DONE_KHR)
    HAZE_RESULT(VK_OPERATION_DEFERRED_KHR)
    HAZE_RESULT(VK_OPERATION_NOT_DEFERRED_KHR)
    HAZE_RESULT(VK_ERROR_COMPRESSION_EXHAUSTED_EXT)
#undef HAZE_RESULT
    default:
      return fmt::format("VkResult({})", static_cast<int>(r));
  }
}

void vk_check(VkResult r, std::string_view what) {
  if (r != VK_SUCCESS) throw Error(fmt::format("{} failed: {}", what, result_name(r)));
}

void vk_check_alloc(VkResult r, std::string_view what, const std::function<std::string()>& oom_message) {
  if (r == VK_ERROR_OUT_OF_DEVICE_MEMORY || r == VK_ERROR_OUT_OF_HOST_MEMORY) throw Error(oom_message());
  vk_check(r, what);
}

std::string printable(const char* text) {
  std::string out;
  for (const char* c = text; c && *c; ++c) {
    const unsigned char u = static_cast<unsigned char>(*c);
    out += u >= 32 && u < 127 ? std::string(1, *c) : fmt::format("\\x{:02x}", u);
  }
  return out;
}

std::string format_bytes(uint64_t bytes) {
  if (bytes < 1024) return fmt::format("{} B", bytes);
  static const char* units[] = {"KiB", "MiB", "GiB", "TiB", "PiB"};
  double v = static_cast<double>(bytes) / 1024.0;
  int u = 0;
  while (v >= 1024.0 && u < 4) {
    v /= 1024.0;
    ++u;
  }
  return fmt::format("{:.1f} {}", v, units[u]);
}

}  // namespace haze::gpu
