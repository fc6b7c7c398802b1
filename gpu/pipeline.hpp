#pragma once
// Compute pipelines from SPIR-V files: storage buffers and images bound by push descriptors, plus push
// constants.

#include <vulkan/vulkan.h>

#include <array>
#include <cstdint>
#include <initializer_list>
#include <span>
#include <string>
#include <vector>

#include "gpu/error.hpp"

namespace haze::gpu {

class Context;
class Buffer;
class Image;

// The words of a SPIR-V file; throws an Error naming the file when it is missing or not SPIR-V.
std::vector<uint32_t> read_spirv(const std::string& path);

// compute+transfer -> compute+transfer memory barrier: shader or transfer writes become visible to later
// shader and transfer reads and writes. Put one between dependent dispatches.
void compute_barrier(VkCommandBuffer cmd);

// Workgroup count covering n items with groups of `local`.
inline uint32_t div_up(uint64_t n, uint32_t local) {
  if (local == 0) throw Error("div_up: group size 0 (local_size() unknown for this shader?)");
  return static_cast<uint32_t>((n + local - 1) / local);
}


// What a binding of descriptor set 0 holds: a storage buffer (gpu::Buffer) or a storage image (gpu::Image).
enum class Slot { Buffer, Image };

// One resource bound at dispatch; converts from either pointer, so `{&buf, &img}` lists work.
struct Resource {
  Resource(const Buffer* b) : buffer(b) {}  // NOLINT(google-explicit-constructor): implicit on purpose
  Resource(const Image* i) : image(i) {}    // NOLINT(google-explicit-constructor)
  const Buffer* buffer = nullptr;
  const Image* image = nullptr;
};

// Descriptor set 0 = one storage buffer or storage image per slot at bindings 0..n-1
// (VK_KHR_push_descriptor), or `num_buffers` storage buffers; push constants of `push_bytes` (multiple of 4,
// <= 128); specialization constants ids 0..k-1 (uint32). The SPIR-V must use only those bindings, each as the
// kind its slot says. Construction is thread-safe: several pipelines may be created in parallel on one
// Context.
class ComputePipeline {
 public:
  ComputePipeline(Context& ctx, const std::string& spv_path, std::vector<Slot> slots, uint32_t push_bytes,
                  const std::vector<uint32_t>& spec_constants = {});
  ComputePipeline(Context& ctx, const std::string& spv_path, uint32_t num_buffers, uint32_t push_bytes,
                  const std::vector<uint32_t>& spec_constants = {});
  // From SPIR-V words already in memory; `name` stands for the file in messages and object names.
  ComputePipeline(Context& ctx, std::string name, const std::vector<uint32_t>& spirv, std::vector<Slot> slots,
                  uint32_t push_bytes, const std::vector<uint32_t>& spec_constants = {});
  ~ComputePipeline();
  ComputePipeline(ComputePipeline&& other) noexcept;
  ComputePipeline& operator=(ComputePipeline&& other) noexcept;
  ComputePipeline(const ComputePipeline&) = delete;
  ComputePipeline& operator=(const ComputePipeline&) = delete;

  // Binds, pushes the resources (in binding order, each of its slot's kind; a storage image must have the
  // format the shader declares for it) and `push_bytes` of `push`, dispatches gx*gy*gz groups.
  void dispatch(VkCommandBuffer cmd, std::span<const Resource> resources, const void* push, uint32_t gx,
                uint32_t gy = 1, uint32_t gz = 1) const;
  // A template only so that an empty `{}` still picks the buffer list below instead of being ambiguous.
  template <class = void>
  void dispatch(VkCommandBuffer cmd, std::initializer_list<Resource> resources, const void* push, uint32_t gx,
                uint32_t gy = 1, uint32_t gz = 1) const {
    dispatch(cmd, std::span<const Resource>(resources.begin(), resources.size()), push, gx, gy, gz);
  }
  // Buffer-only pipelines.
  void dispatch(VkCommandBuffer cmd, std::initializer_list<const Buffer*> buffers, const void* push,
                uint32_t gx, uint32_t gy = 1, uint32_t gz = 1) const;
  void dispatch(VkCommandBuffer cmd, std::span<const Buffer* const> buffers, const void* push, uint32_t gx,
                uint32_t gy = 1, uint32_t gz = 1) const;

  double creation_ms() const { return creation_ms_; }  // wall time of vkCreateComputePipelines
  const std::string& path() const { return path_; }    // the SPIR-V file, or the name given
  // Workgroup size from the SPIR-V (LocalSize, or WorkgroupSize with the given spec constants); 0 if unknown.
  const std::array<uint32_t, 3>& local_size() const { return local_size_; }
  const std::vector<Slot>& slots() const { return slots_; }
  uint32_t num_buffers() const;  // slots of kind Buffer
  uint32_t push_bytes() const { return push_bytes_; }
  VkPipeline handle() const { return pipeline_; }
  VkPipelineLayout layout() const { return layout_; }

 private:
  void check_layout() const;  // push constant size, binding and image counts against the device
  void create(const std::vector<uint32_t>& words, const std::vector<uint32_t>& spec_constants);
  void release() noexcept;

  Context* ctx_ = nullptr;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
  std::string path_;
  std::vector<Slot> slots_;
  std::vector<VkFormat> image_formats_;  // per binding: the shader's storage image format, UNDEFINED = any
  uint32_t push_bytes_ = 0;
  double creation_ms_ = 0;
  std::array<uint32_t, 3> local_size_{0, 0, 0};
};

}  // namespace haze::gpu
