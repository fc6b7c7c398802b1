#pragma once
// Errors of the GPU layer: one exception type whose text is one clear line.

#include <vulkan/vulkan.h>

#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <string_view>

namespace haze::gpu {

struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// "VK_ERROR_OUT_OF_DEVICE_MEMORY"; unknown codes give "VkResult(-13)".
std::string result_name(VkResult r);

// Throws Error("<what> failed: <VkResult name>") unless r is VK_SUCCESS.
void vk_check(VkResult r, std::string_view what);

// Like vk_check, but an out-of-memory result throws Error(oom_message()) instead: allocations name what
// they were allocating and how much.
void vk_check_alloc(VkResult r, std::string_view what, const std::function<std::string()>& oom_message);

// "512 B", "3.0 KiB", "1.2 GiB": for messages and reports.
std::string format_bytes(uint64_t bytes);

// Text with every byte outside printable ASCII written as \xNN, for messages that quote a library's text
// (stb's failure reason for an unknown PNG chunk holds the chunk's four raw bytes); null gives "".
std::string printable(const char* text);

}  // namespace haze::gpu

// HAZE_VK(vkCreateBuffer(dev, &info, nullptr, &buf)) throws "vkCreateBuffer failed: VK_ERROR_...".
#define HAZE_VK(call) ::haze::gpu::detail::check_call((call), #call)

namespace haze::gpu::detail {
// Names the function from the stringified call (text before the first '(').
inline void check_call(VkResult r, std::string_view call) {
  if (r == VK_SUCCESS) return;
  vk_check(r, call.substr(0, call.find('(')));
}
}  // namespace haze::gpu::detail
