#pragma once
// Compute pipelines from SPIR-V files: storage buffers bound by push descriptors, plus push constants.

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

// Path of a variant built by haze_shader() (cmake/HazeShaders.cmake): "<spv_dir>/<source>.<mask>.spv".
std::string variant_spv(const std::string& spv_dir, const std::string& source, uint32_t mask);

// Descriptor set 0 = `num_buffers` storage buffers at bindings 0..n-1 (VK_KHR_push_descriptor);
// push constants of `push_bytes` (multiple of 4, <= 128); specialization constants ids 0..k-1 (uint32).
// Construction is thread-safe: several pipelines may be created in parallel on one Context.
class ComputePipeline {
 public:
  ComputePipeline(Context& ctx, const std::string& spv_path, uint32_t num_buffers, uint32_t push_bytes,
                  const std::vector<uint32_t>& spec_constants = {});
  ~ComputePipeline();
  ComputePipeline(ComputePipeline&& other) noexcept;
  ComputePipeline& operator=(ComputePipeline&& other) noexcept;
  ComputePipeline(const ComputePipeline&) = delete;
  ComputePipeline& operator=(const ComputePipeline&) = delete;

  // Binds, pushes buffers (in binding order) and `push_bytes` of `push`, dispatches gx*gy*gz groups.
  void dispatch(VkCommandBuffer cmd, std::initializer_list<const Buffer*> buffers, const void* push,
                uint32_t gx, uint32_t gy = 1, uint32_t gz = 1) const;
  void dispatch(VkCommandBuffer cmd, std::span<const Buffer* const> buffers, const void* push, uint32_t gx,
                uint32_t gy = 1, uint32_t gz = 1) const;

  double creation_ms() const { return creation_ms_; }  // wall time of vkCreateComputePipelines
  const std::string& path() const { return path_; }
  // Workgroup size from the SPIR-V (LocalSize, or WorkgroupSize with the given spec constants); 0 if unknown.
  const std::array<uint32_t, 3>& local_size() const { return local_size_; }
  uint32_t num_buffers() const { return num_buffers_; }
  uint32_t push_bytes() const { return push_bytes_; }
  VkPipeline handle() const { return pipeline_; }
  VkPipelineLayout layout() const { return layout_; }

 private:
  void release() noexcept;

  Context* ctx_ = nullptr;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_ = VK_NULL_HANDLE;
  std::string path_;
  uint32_t num_buffers_ = 0, push_bytes_ = 0;
  double creation_ms_ = 0;
  std::array<uint32_t, 3> local_size_{0, 0, 0};
};

}  // namespace haze::gpu
