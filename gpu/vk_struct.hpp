#pragma once
// Zeroed Vulkan info struct with sType (and pNext) set. Spelled as a function because GCC 12 warns
// (-Wmissing-field-initializers) on partial aggregate and designated initializers.

#include <vulkan/vulkan.h>

#include <cstddef>

namespace haze::gpu {

template <class T, class Next = std::nullptr_t>
T vk_struct(VkStructureType type, Next next = nullptr) {
  T t{};
  t.sType = type;
  t.pNext = next;
  return t;
}

}  // namespace haze::gpu
