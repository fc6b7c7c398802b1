#pragma once
// The Vulkan instance, one device with one compute queue, and the process-wide helpers around them
// (command submission, pipeline cache, validation message counting, the memory ledger).

#include <vulkan/vulkan.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gpu/ledger.hpp"
#include "gpu/shader_compiler.hpp"

namespace haze::gpu {

class KernelCache;

struct ContextOptions {
  // "" -> env HAZE_DEVICE -> auto (discrete > integrated > virtual > cpu).
  // A decimal index (as in list_devices()) or a case-insensitive substring of the device name.
  std::string device;
  bool validation = false;  // also switched on by env HAZE_VALIDATION=1 ("sync" adds synchronization checks)
  std::string pipeline_cache;  // VkPipelineCache file to load and save ("" = none)
  bool force_staging = false;  // tests: move data through staging buffers even when memory is host-visible
  std::string shader_cache;    // SPIR-V cache folder of shaders() ("" = ShaderCompiler::default_cache_dir())
  // What a window needs (haze view): the instance extensions of its surface (VK_KHR_surface and the
  // platform's), device extensions (VK_KHR_swapchain), and a queue family that also does graphics (the UI
  // draws with a render pass). A device without them is an error naming what it lacks.
  std::vector<std::string> instance_extensions;
  std::vector<std::string> device_extensions;
  bool graphics = false;
};

// Optional device capabilities, each enabled when the device has it.
struct DeviceFeatures {
  bool int64 = false, float64 = false, int16 = false, int8 = false, float16 = false;
  bool storage_8bit = false, storage_16bit = false, scalar_layout = false;
  bool buffer_device_address = false, buffer_int64_atomics = false;
  bool atomic_float_add = false;  // VK_EXT_shader_atomic_float, buffer float32 atomicAdd
  bool subgroup_size_control = false;
  bool subgroup_arithmetic = false;  // compute shaders' subgroupAdd and subgroupElect
  bool timestamps = false;           // the queue writes timestamps
  uint32_t subgroup_size = 0;
};

class Context {
 public:
  explicit Context(const ContextOptions& options = {});
  ~Context();  // waits idle, saves the pipeline cache
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  VkInstance instance() const { return instance_; }
  VkPhysicalDevice physical() const { return physical_; }
  VkDevice device() const { return device_; }
  VkQueue queue() const { return queue_; }
  uint32_t queue_family() const { return family_; }

  const std::string& device_name() const { return name_; }
  std::string driver_info() const;  // "llvmpipe Mesa 25.0.7 (LLVM 15.0.6)"
  bool is_cpu() const;              // lavapipe or VK_PHYSICAL_DEVICE_TYPE_CPU
  bool is_discrete() const { return props_.deviceType == VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU; }
  nlohmann::json describe() const;  // {name, type, driver, api_version, index, ...}
  uint32_t device_index() const { return index_; }

  const DeviceFeatures& features() const { return features_; }
  const VkPhysicalDeviceLimits& limits() const { return props_.limits; }
  const VkPhysicalDeviceMemoryProperties& memory_properties() const { return memory_; }
  uint64_t max_allocation_size() const { return max_allocation_; }  // maxMemoryAllocationSize
  uint64_t max_buffer_size() const { return max_buffer_; }          // maxBufferSize (maintenance4)
  bool force_staging() const { return force_staging_; }

  // GLSL -> SPIR-V for this context's pipelines (the embedded sources, cached in options.shader_cache).
  ShaderCompiler& shaders() { return shaders_; }
  const ShaderCompiler& shaders() const { return shaders_; }
  // The pipelines of every kernel made on this context, created once (gpu/kernel.hpp).
  KernelCache& kernels() { return *kernels_; }

  MemoryLedger& ledger() { return ledger_; }
  const MemoryLedger& ledger() const { return ledger_; }

  float timestamp_period_ns() const { return props_.limits.timestampPeriod; }
  uint32_t timestamp_valid_bits() const { return timestamp_bits_; }

  bool validation_enabled() const { return messenger_ != VK_NULL_HANDLE; }
  uint64_t validation_messages() const { return validation_count_.load(); }  // warnings + errors
  std::vector<std::string> validation_log() const;
  // Counts another context's messages as this one's (a helper context this one made).
  void take_validation_messages(const Context& helper);
  // What this context was made with (a helper context on the same device is made with the same).
  const ContextOptions& options() const { return options_; }

  VkPipelineCache pipeline_cache() const { return pipeline_cache_; }
  void save_pipeline_cache() const;  // atomically (tmp + rename); no-op without a path

  // Records with `record`, submits on the queue and waits. Reuses one command buffer; thread-safe
  // (submissions are serialized); calling it from inside `record` throws.
  void submit_and_wait(const std::function<void(VkCommandBuffer)>& record);
  // Submits one batch and presents, each under the queue's lock (a queue is externally synchronized, and
  // submit_and_wait may run on another thread).
  void submit(const VkSubmitInfo& info, VkFence fence);
  VkResult present(const VkPresentInfoKHR& info);

  // Submissions the host does not wait for (gpu::FrameRing) register their fence while they run. Every
  // host access to device memory that one of them may use (Buffer upload, download and destruction, Image
  // destruction) first waits for them all: correct whatever the caller does, and counted, so a frame loop
  // can show where it stalls (host_waits()).
  void track_in_flight(VkFence fence);
  void untrack_in_flight(VkFence fence);
  void wait_in_flight();
  uint64_t host_waits() const { return host_waits_.load(); }  // wait_in_flight() calls that had to wait

  // Names an object in validation messages (no-op without validation).
  void set_object_name(VkObjectType type, uint64_t handle, const std::string& name) const;

  // vkCmdPushDescriptorSetKHR, loaded at device creation.
  PFN_vkCmdPushDescriptorSetKHR cmd_push_descriptor_set() const { return push_descriptor_; }

 private:
  void destroy() noexcept;
  void on_validation_message(const char* text);
  static VKAPI_ATTR VkBool32 VKAPI_CALL debug_callback(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                                       VkDebugUtilsMessageTypeFlagsEXT types,
                                                       const VkDebugUtilsMessengerCallbackDataEXT* data,
                                                       void* user);

  ContextOptions options_;
  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  uint32_t family_ = 0;
  uint32_t index_ = 0;
  std::string name_;
  VkPhysicalDeviceProperties props_{};
  VkPhysicalDeviceDriverProperties driver_{};
  VkPhysicalDeviceMemoryProperties memory_{};
  uint64_t max_allocation_ = 0, max_buffer_ = 0;
  uint32_t timestamp_bits_ = 0;
  DeviceFeatures features_;
  bool force_staging_ = false;
  PFN_vkCmdPushDescriptorSetKHR push_descriptor_ = nullptr;
  PFN_vkSetDebugUtilsObjectNameEXT set_name_ = nullptr;

  VkPipelineCache pipeline_cache_ = VK_NULL_HANDLE;
  std::string cache_path_;

  std::recursive_mutex submit_mutex_;  // recursive only so a nested call can be detected and refused
  bool recording_ = false;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;

  std::mutex in_flight_mutex_;
  std::vector<VkFence> in_flight_;
  std::atomic<uint64_t> host_waits_{0};

  MemoryLedger ledger_;
  ShaderCompiler shaders_;
  std::unique_ptr<KernelCache> kernels_;

  std::atomic<uint64_t> validation_count_{0};
  mutable std::mutex log_mutex_;
  std::vector<std::string> validation_log_;
};

namespace detail {
// The refusal message for lavapipe older than Mesa 24 (driver_info "Mesa 22.3.6 ..."), else "".
std::string old_lavapipe_message(VkDriverId driver, const char* driver_info);
}  // namespace detail

// One JSON object per Vulkan device, for `haze --list-devices`:
// {index, name, type, driver, api_version, suitable, reason, ...}.
std::vector<nlohmann::json> list_devices();

}  // namespace haze::gpu
