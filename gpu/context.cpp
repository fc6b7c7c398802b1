#include "gpu/context.hpp"

#if defined(__SSE__) || defined(__x86_64__)
#include <xmmintrin.h>
#endif

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>

#include "gpu/error.hpp"
#include "gpu/kernel.hpp"
#include "gpu/vk_struct.hpp"

namespace haze::gpu {
namespace {

constexpr const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";

std::string env(const char* name) {
  const char* v = std::getenv(name);
  return v ? std::string(v) : std::string();
}

std::string lower(std::string s) {
  for (auto& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

const char* type_name(VkPhysicalDeviceType t) {
  switch (t) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return "discrete";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return "integrated";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return "virtual";
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return "cpu";
    default:
      return "other";
  }
}

int type_score(VkPhysicalDeviceType t) {
  switch (t) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU:
      return 4;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU:
      return 3;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU:
      return 2;
    case VK_PHYSICAL_DEVICE_TYPE_CPU:
      return 1;
    default:
      return 0;
  }
}

std::string api_string(uint32_t v) {
  return fmt::format("{}.{}.{}", VK_API_VERSION_MAJOR(v), VK_API_VERSION_MINOR(v), VK_API_VERSION_PATCH(v));
}

// "Mesa 25.0.7 (LLVM 15.0.6)" -> {25, 0}.
std::optional<std::pair<int, int>> mesa_version(const char* info) {
  const char* p = std::strstr(info, "Mesa ");
  int major = 0, minor = 0;
  if (!p || std::sscanf(p + 5, "%d.%d", &major, &minor) != 2) return std::nullopt;
  return std::pair{major, minor};
}

std::vector<VkExtensionProperties> device_extensions(VkPhysicalDevice phys) {
  uint32_t n = 0;
  vkEnumerateDeviceExtensionProperties(phys, nullptr, &n, nullptr);
  std::vector<VkExtensionProperties> out(n);
  vkEnumerateDeviceExtensionProperties(phys, nullptr, &n, out.data());
  out.resize(n);
  return out;
}

bool has_extension(const std::vector<VkExtensionProperties>& list, const char* name) {
  return std::any_of(list.begin(), list.end(),
                     [&](const VkExtensionProperties& e) { return std::strcmp(e.extensionName, name) == 0; });
}

// The first compute family that writes timestamps, else the first compute family, else -1; with
// `graphics`, only families that also do graphics.
int pick_family(VkPhysicalDevice phys, uint32_t* timestamp_bits, bool graphics = false) {
  uint32_t n = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(phys, &n, nullptr);
  std::vector<VkQueueFamilyProperties> fams(n);
  vkGetPhysicalDeviceQueueFamilyProperties(phys, &n, fams.data());
  int any = -1;
  for (uint32_t i = 0; i < n; ++i) {
    if (!(fams[i].queueFlags & VK_QUEUE_COMPUTE_BIT)) continue;
    if (graphics && !(fams[i].queueFlags & VK_QUEUE_GRAPHICS_BIT)) continue;
    if (fams[i].timestampValidBits > 0) {
      if (timestamp_bits) *timestamp_bits = fams[i].timestampValidBits;
      return static_cast<int>(i);
    }
    if (any < 0) any = static_cast<int>(i);
  }
  if (timestamp_bits) *timestamp_bits = 0;
  return any;
}

struct Candidate {
  uint32_t index = 0;
  VkPhysicalDevice phys = VK_NULL_HANDLE;
  VkPhysicalDeviceProperties props{};
  VkPhysicalDeviceDriverProperties driver{};
  std::string reason;  // why haze cannot use it; empty = suitable

  bool lavapipe() const { return driver.driverID == VK_DRIVER_ID_MESA_LLVMPIPE; }
  std::string driver_text() const {
    if (driver.driverName[0] == 0) return api_string(props.driverVersion);
    return driver.driverInfo[0] ? fmt::format("{} {}", driver.driverName, driver.driverInfo)
                                : std::string(driver.driverName);
  }
};

Candidate inspect(VkPhysicalDevice phys, uint32_t index) {
  Candidate c;
  c.index = index;
  c.phys = phys;
  vkGetPhysicalDeviceProperties(phys, &c.props);
  auto exts = device_extensions(phys);
  if (c.props.apiVersion >= VK_API_VERSION_1_2 ||
      has_extension(exts, VK_KHR_DRIVER_PROPERTIES_EXTENSION_NAME)) {
    c.driver.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES;
    auto p2 =
        vk_struct<VkPhysicalDeviceProperties2>(VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &c.driver);
    vkGetPhysicalDeviceProperties2(phys, &p2);
  }
  std::string name = c.props.deviceName;
  if (c.props.apiVersion < VK_API_VERSION_1_3) {
    c.reason =
        fmt::format("'{}' supports Vulkan {} only; haze needs 1.3", name, api_string(c.props.apiVersion));
  } else if (pick_family(phys, nullptr) < 0) {
    c.reason = fmt::format("'{}' has no compute queue", name);
  } else if (!has_extension(exts, VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME)) {
    c.reason = fmt::format("'{}' lacks {}", name, VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME);
  } else {
    c.reason = detail::old_lavapipe_message(c.driver.driverID, c.driver.driverInfo);
  }
  return c;
}

std::vector<Candidate> enumerate(VkInstance instance) {
  uint32_t n = 0;
  HAZE_VK(vkEnumeratePhysicalDevices(instance, &n, nullptr));
  std::vector<VkPhysicalDevice> phys(n);
  VkResult r = vkEnumeratePhysicalDevices(instance, &n, phys.data());
  if (r != VK_SUCCESS && r != VK_INCOMPLETE) vk_check(r, "vkEnumeratePhysicalDevices");
  std::vector<Candidate> out;
  for (uint32_t i = 0; i < n; ++i) out.push_back(inspect(phys[i], i));
  return out;
}

std::string short_line(const Candidate& c) {
  return fmt::format("{}: {} [{}]", c.index, c.props.deviceName, type_name(c.props.deviceType));
}

std::string available_list(const std::vector<Candidate>& cs) {
  std::string s;
  for (const auto& c : cs) s += (s.empty() ? "" : ", ") + short_line(c);
  return s;
}

const Candidate& select_device(const std::vector<Candidate>& cs, const std::string& want) {
  if (cs.empty())
    throw Error(
        "no Vulkan device found: install a driver (scripts/setup.sh installs lavapipe) or check "
        "VK_DRIVER_FILES");
  const Candidate* chosen = nullptr;
  if (!want.empty()) {
    bool digits = want.size() <= 9 && std::all_of(want.begin(), want.end(), [](char ch) {
                    return std::isdigit(static_cast<unsigned char>(ch));
                  });
    if (digits) {
      auto idx = std::stoul(want);
      if (idx < cs.size()) chosen = &cs[idx];
    } else {
      std::string w = lower(want);
      for (const auto& c : cs) {
        if (lower(c.props.deviceName).find(w) == std::string::npos) continue;
        if (!chosen || (!chosen->reason.empty() && c.reason.empty())) chosen = &c;  // prefer a usable match
      }
    }
    if (!chosen)
      throw Error(fmt::format("no Vulkan device matches '{}'; available: {}", want, available_list(cs)));
    if (!chosen->reason.empty()) throw Error(chosen->reason);
    return *chosen;
  }
  for (const auto& c : cs) {
    if (!c.reason.empty()) continue;
    if (!chosen || type_score(c.props.deviceType) > type_score(chosen->props.deviceType)) chosen = &c;
  }
  if (chosen) return *chosen;
  for (const auto& c : cs)
    if (c.lavapipe()) throw Error(c.reason);  // the one message that says what to install
  std::string why;
  for (const auto& c : cs) why += (why.empty() ? "" : "; ") + c.reason;
  throw Error(fmt::format("no Vulkan device can run haze: {}", why));
}

nlohmann::json candidate_json(const Candidate& c) {
  nlohmann::json j = {{"index", c.index},
                      {"name", c.props.deviceName},
                      {"type", type_name(c.props.deviceType)},
                      {"driver", c.driver_text()},
                      {"api_version", api_string(c.props.apiVersion)},
                      {"vendor_id", c.props.vendorID},
                      {"device_id", c.props.deviceID},
                      {"suitable", c.reason.empty()}};
  if (!c.reason.empty()) j["reason"] = c.reason;
  VkPhysicalDeviceMemoryProperties mem;
  vkGetPhysicalDeviceMemoryProperties(c.phys, &mem);
  uint64_t local = 0;
  for (uint32_t i = 0; i < mem.memoryHeapCount; ++i)
    if (mem.memoryHeaps[i].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) local += mem.memoryHeaps[i].size;
  j["device_local_bytes"] = local;
  return j;
}

// While alive, the calling thread flushes denormal floats to zero (SSE's FTZ and DAZ), and so does every
// thread it starts: POSIX threads inherit the floating-point environment. A CPU driver (lavapipe) starts its
// shader threads while the instance and device are created, so its shaders run with FTZ and DAZ, as Vulkan
// permits for 32-bit floats without the DenormPreserve mode. Without them each operation on a denormal
// costs a microcode assist: a kernel whose values decay into the denormal range (exp(-x) past x = 87, a
// transmittance, a filter weight) ran 20 times slower on lavapipe. The calling thread's own mode is
// restored.
class FlushDenormalsInNewThreads {
 public:
  FlushDenormalsInNewThreads() {
#if defined(__SSE__) || defined(__x86_64__)
    saved_ = _mm_getcsr();
    _mm_setcsr(saved_ | kFlushToZero | kDenormalsAreZero);
#endif
  }
  ~FlushDenormalsInNewThreads() {
#if defined(__SSE__) || defined(__x86_64__)
    _mm_setcsr(saved_);
#endif
  }
  FlushDenormalsInNewThreads(const FlushDenormalsInNewThreads&) = delete;
  FlushDenormalsInNewThreads& operator=(const FlushDenormalsInNewThreads&) = delete;

 private:
  static constexpr unsigned kFlushToZero = 0x8000, kDenormalsAreZero = 0x0040;
  unsigned saved_ = 0;
};

VkInstance create_instance(const std::vector<const char*>& layers, const std::vector<const char*>& exts,
                           const void* next) {
  uint32_t loader = VK_API_VERSION_1_0;
  vkEnumerateInstanceVersion(&loader);
  if (loader < VK_API_VERSION_1_3)
    throw Error(fmt::format("the Vulkan loader supports {} only; haze needs 1.3", api_string(loader)));
  auto app = vk_struct<VkApplicationInfo>(VK_STRUCTURE_TYPE_APPLICATION_INFO);
  app.pApplicationName = "haze";
  app.pEngineName = "haze";
  app.apiVersion = VK_API_VERSION_1_3;
  auto info = vk_struct<VkInstanceCreateInfo>(VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO);
  info.pNext = next;
  info.pApplicationInfo = &app;
  info.enabledLayerCount = static_cast<uint32_t>(layers.size());
  info.ppEnabledLayerNames = layers.data();
  info.enabledExtensionCount = static_cast<uint32_t>(exts.size());
  info.ppEnabledExtensionNames = exts.data();
  VkInstance instance = VK_NULL_HANDLE;
  VkResult r = vkCreateInstance(&info, nullptr, &instance);
  if (r == VK_ERROR_INCOMPATIBLE_DRIVER)
    throw Error(
        "vkCreateInstance failed: VK_ERROR_INCOMPATIBLE_DRIVER (no Vulkan 1.3 driver; run scripts/setup.sh)");
  vk_check(r, "vkCreateInstance");
  return instance;
}

bool layer_present(const char* name) {
  uint32_t n = 0;
  vkEnumerateInstanceLayerProperties(&n, nullptr);
  std::vector<VkLayerProperties> layers(n);
  vkEnumerateInstanceLayerProperties(&n, layers.data());
  for (uint32_t i = 0; i < n; ++i)
    if (std::strcmp(layers[i].layerName, name) == 0) return true;
  return false;
}

bool instance_extension_present(const char* layer, const char* name) {
  uint32_t n = 0;
  vkEnumerateInstanceExtensionProperties(layer, &n, nullptr);
  std::vector<VkExtensionProperties> exts(n);
  vkEnumerateInstanceExtensionProperties(layer, &n, exts.data());
  exts.resize(n);
  return has_extension(exts, name);
}

// A cache file is only handed to the driver when its header names this exact device and driver build;
// some drivers do not survive foreign data.
bool cache_matches(const std::vector<char>& data, const VkPhysicalDeviceProperties& p) {
  if (data.size() < 16 + VK_UUID_SIZE) return false;
  uint32_t h[4];
  std::memcpy(h, data.data(), sizeof h);
  return h[0] >= 16 + VK_UUID_SIZE && h[1] == VK_PIPELINE_CACHE_HEADER_VERSION_ONE && h[2] == p.vendorID &&
         h[3] == p.deviceID && std::memcmp(data.data() + 16, p.pipelineCacheUUID, VK_UUID_SIZE) == 0;
}

}  // namespace

std::string detail::old_lavapipe_message(VkDriverId driver, const char* driver_info) {
  if (driver != VK_DRIVER_ID_MESA_LLVMPIPE) return {};
  // Mesa 22/23 lavapipe cuts long loops silently, which corrupts ray marches without any error.
  auto v = mesa_version(driver_info);
  if (!v || v->first >= 24) return {};
  return fmt::format(
      "lavapipe from Mesa {}.{} silently truncates long shader loops; install Mesa >= 24 "
      "(scripts/setup.sh installs it from bookworm-backports)",
      v->first, v->second);
}

VKAPI_ATTR VkBool32 VKAPI_CALL Context::debug_callback(VkDebugUtilsMessageSeverityFlagBitsEXT,
                                                       VkDebugUtilsMessageTypeFlagsEXT,
                                                       const VkDebugUtilsMessengerCallbackDataEXT* data,
                                                       void* user) {
  static_cast<Context*>(user)->on_validation_message(data && data->pMessage ? data->pMessage : "(no text)");
  return VK_FALSE;  // never abort the call: the count is what tests check
}

void Context::on_validation_message(const char* text) {
  validation_count_.fetch_add(1);
  std::lock_guard lock(log_mutex_);
  std::fprintf(stderr, "vulkan validation: %s\n", text);
  validation_log_.emplace_back(text);
}

std::vector<std::string> Context::validation_log() const {
  std::lock_guard lock(log_mutex_);
  return validation_log_;
}

void Context::take_validation_messages(const Context& helper) {
  const std::vector<std::string> log = helper.validation_log();
  std::lock_guard lock(log_mutex_);
  validation_count_.fetch_add(helper.validation_messages());
  validation_log_.insert(validation_log_.end(), log.begin(), log.end());
}

Context::Context(const ContextOptions& options)
    : options_(options), shaders_(options.shader_cache), kernels_(std::make_unique<KernelCache>(*this)) {
  FlushDenormalsInNewThreads flush_denormals;
  try {
    std::string venv = lower(env("HAZE_VALIDATION"));
    bool sync = venv == "sync";
    bool validation =
        options.validation || sync || venv == "1" || venv == "true" || venv == "on" || venv == "yes";
    force_staging_ = options.force_staging;

    std::vector<const char*> layers, exts;
    auto dbg = vk_struct<VkDebugUtilsMessengerCreateInfoEXT>(
        VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT);
    dbg.messageSeverity =
        VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
    dbg.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT |
                      VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                      VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
    dbg.pfnUserCallback = &Context::debug_callback;
    dbg.pUserData = this;
    VkValidationFeatureEnableEXT sync_feature = VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT;
    auto vfeatures = vk_struct<VkValidationFeaturesEXT>(VK_STRUCTURE_TYPE_VALIDATION_FEATURES_EXT);
    const void* next = nullptr;
    if (validation) {
      if (!layer_present(kValidationLayer))
        throw Error(fmt::format("validation requested but {} is not installed: run scripts/setup.sh",
                                kValidationLayer));
      layers.push_back(kValidationLayer);
      if (!instance_extension_present(kValidationLayer, VK_EXT_DEBUG_UTILS_EXTENSION_NAME) &&
          !instance_extension_present(nullptr, VK_EXT_DEBUG_UTILS_EXTENSION_NAME))
        throw Error("validation requested but VK_EXT_debug_utils is not available");
      exts.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
      next = &dbg;  // also catches messages from vkCreateInstance / vkDestroyInstance
      if (sync && instance_extension_present(kValidationLayer, VK_EXT_VALIDATION_FEATURES_EXTENSION_NAME)) {
        exts.push_back(VK_EXT_VALIDATION_FEATURES_EXTENSION_NAME);
        vfeatures.enabledValidationFeatureCount = 1;
        vfeatures.pEnabledValidationFeatures = &sync_feature;
        vfeatures.pNext = &dbg;
        next = &vfeatures;
      }
    }
    for (const auto& e : options.instance_extensions) {
      if (!instance_extension_present(nullptr, e.c_str()))
        throw Error(
            fmt::format("the Vulkan instance lacks {}, which a window needs: install the loader's "
                        "window-system support (scripts/setup.sh)",
                        e));
      exts.push_back(e.c_str());
    }
    instance_ = create_instance(layers, exts, next);
    if (validation) {
      auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
          vkGetInstanceProcAddr(instance_, "vkCreateDebugUtilsMessengerEXT"));
      if (!create) throw Error("vkCreateDebugUtilsMessengerEXT is missing");
      HAZE_VK(create(instance_, &dbg, nullptr, &messenger_));
      set_name_ = reinterpret_cast<PFN_vkSetDebugUtilsObjectNameEXT>(
          vkGetInstanceProcAddr(instance_, "vkSetDebugUtilsObjectNameEXT"));
    }

    // Device.
    auto candidates = enumerate(instance_);
    std::string want = options.device.empty() ? env("HAZE_DEVICE") : options.device;
    const Candidate& chosen = select_device(candidates, want);
    physical_ = chosen.phys;
    index_ = chosen.index;
    props_ = chosen.props;
    driver_ = chosen.driver;
    driver_.pNext = nullptr;
    name_ = props_.deviceName;
    const int family = pick_family(physical_, &timestamp_bits_, options.graphics);
    if (family < 0)
      throw Error(
          fmt::format("'{}' has no queue that does both compute and graphics, which the viewer needs; "
                      "pick another device with --device",
                      name_));
    family_ = static_cast<uint32_t>(family);
    vkGetPhysicalDeviceMemoryProperties(physical_, &memory_);

    auto subgroup =
        vk_struct<VkPhysicalDeviceSubgroupProperties>(VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES);
    auto m4 = vk_struct<VkPhysicalDeviceMaintenance4Properties>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_MAINTENANCE_4_PROPERTIES, &subgroup);
    auto m3 = vk_struct<VkPhysicalDeviceMaintenance3Properties>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_MAINTENANCE_3_PROPERTIES, &m4);
    auto p2 = vk_struct<VkPhysicalDeviceProperties2>(VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &m3);
    vkGetPhysicalDeviceProperties2(physical_, &p2);
    max_allocation_ = m3.maxMemoryAllocationSize;
    max_buffer_ = m4.maxBufferSize;

    // Features: enable what haze's shaders may use, each only where the device has it.
    auto exts_dev = device_extensions(physical_);
    bool atomic_float = has_extension(exts_dev, VK_EXT_SHADER_ATOMIC_FLOAT_EXTENSION_NAME);
    auto haf = vk_struct<VkPhysicalDeviceShaderAtomicFloatFeaturesEXT>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SHADER_ATOMIC_FLOAT_FEATURES_EXT);
    auto h13 = vk_struct<VkPhysicalDeviceVulkan13Features>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES, atomic_float ? &haf : nullptr);
    auto h12 = vk_struct<VkPhysicalDeviceVulkan12Features>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES, &h13);
    auto h11 = vk_struct<VkPhysicalDeviceVulkan11Features>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_FEATURES, &h12);
    auto have = vk_struct<VkPhysicalDeviceFeatures2>(VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &h11);
    vkGetPhysicalDeviceFeatures2(physical_, &have);

    auto waf = vk_struct<VkPhysicalDeviceShaderAtomicFloatFeaturesEXT>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SHADER_ATOMIC_FLOAT_FEATURES_EXT);
    auto w13 = vk_struct<VkPhysicalDeviceVulkan13Features>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES, atomic_float ? &waf : nullptr);
    auto w12 = vk_struct<VkPhysicalDeviceVulkan12Features>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES, &w13);
    auto w11 = vk_struct<VkPhysicalDeviceVulkan11Features>(
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_FEATURES, &w12);
    auto want_f = vk_struct<VkPhysicalDeviceFeatures2>(VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &w11);
    want_f.features.shaderInt64 = have.features.shaderInt64;
    want_f.features.shaderFloat64 = have.features.shaderFloat64;
    want_f.features.shaderInt16 = have.features.shaderInt16;
    w11.storageBuffer16BitAccess = h11.storageBuffer16BitAccess;
    w12.storageBuffer8BitAccess = h12.storageBuffer8BitAccess;
    w12.shaderInt8 = h12.shaderInt8;
    w12.shaderFloat16 = h12.shaderFloat16;
    w12.scalarBlockLayout = h12.scalarBlockLayout;
    w12.bufferDeviceAddress = h12.bufferDeviceAddress;
    w12.shaderBufferInt64Atomics = h12.shaderBufferInt64Atomics;
    w12.shaderSharedInt64Atomics = h12.shaderSharedInt64Atomics;
    w12.hostQueryReset = h12.hostQueryReset;
    w12.timelineSemaphore = h12.timelineSemaphore;
    w12.vulkanMemoryModel = h12.vulkanMemoryModel;
    w12.vulkanMemoryModelDeviceScope = h12.vulkanMemoryModelDeviceScope;
    w13.synchronization2 = h13.synchronization2;
    w13.maintenance4 = h13.maintenance4;
    w13.subgroupSizeControl = h13.subgroupSizeControl;
    w13.computeFullSubgroups = h13.computeFullSubgroups;
    w13.shaderIntegerDotProduct = h13.shaderIntegerDotProduct;
    w13.shaderZeroInitializeWorkgroupMemory = h13.shaderZeroInitializeWorkgroupMemory;
    w13.pipelineCreationCacheControl = h13.pipelineCreationCacheControl;
    waf.shaderBufferFloat32Atomics = haf.shaderBufferFloat32Atomics;
    waf.shaderBufferFloat32AtomicAdd = haf.shaderBufferFloat32AtomicAdd;
    waf.shaderSharedFloat32Atomics = haf.shaderSharedFloat32Atomics;
    waf.shaderSharedFloat32AtomicAdd = haf.shaderSharedFloat32AtomicAdd;

    features_.int64 = want_f.features.shaderInt64;
    features_.float64 = want_f.features.shaderFloat64;
    features_.int16 = want_f.features.shaderInt16;
    features_.int8 = w12.shaderInt8;
    features_.float16 = w12.shaderFloat16;
    features_.storage_8bit = w12.storageBuffer8BitAccess;
    features_.storage_16bit = w11.storageBuffer16BitAccess;
    features_.scalar_layout = w12.scalarBlockLayout;
    features_.buffer_device_address = w12.bufferDeviceAddress;
    features_.buffer_int64_atomics = w12.shaderBufferInt64Atomics;
    features_.atomic_float_add = atomic_float && waf.shaderBufferFloat32AtomicAdd;
    features_.subgroup_size_control = w13.subgroupSizeControl;
    features_.timestamps = timestamp_bits_ > 0;
    features_.subgroup_size = subgroup.subgroupSize;
    features_.subgroup_arithmetic = (subgroup.supportedStages & VK_SHADER_STAGE_COMPUTE_BIT) &&
                                    (subgroup.supportedOperations & VK_SUBGROUP_FEATURE_BASIC_BIT) &&
                                    (subgroup.supportedOperations & VK_SUBGROUP_FEATURE_ARITHMETIC_BIT);

    std::vector<const char*> dev_exts = {VK_KHR_PUSH_DESCRIPTOR_EXTENSION_NAME};
    if (atomic_float) dev_exts.push_back(VK_EXT_SHADER_ATOMIC_FLOAT_EXTENSION_NAME);
    for (const auto& e : options.device_extensions) {
      if (!has_extension(exts_dev, e.c_str()))
        throw Error(
            fmt::format("'{}' lacks {}, which a window needs; pick another device with --device", name_, e));
      dev_exts.push_back(e.c_str());
    }
    float priority = 1.0f;
    auto qinfo = vk_struct<VkDeviceQueueCreateInfo>(VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO);
    qinfo.queueFamilyIndex = family_;
    qinfo.queueCount = 1;
    qinfo.pQueuePriorities = &priority;
    auto dinfo = vk_struct<VkDeviceCreateInfo>(VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &want_f);
    dinfo.queueCreateInfoCount = 1;
    dinfo.pQueueCreateInfos = &qinfo;
    dinfo.enabledExtensionCount = static_cast<uint32_t>(dev_exts.size());
    dinfo.ppEnabledExtensionNames = dev_exts.data();
    HAZE_VK(vkCreateDevice(physical_, &dinfo, nullptr, &device_));
    vkGetDeviceQueue(device_, family_, 0, &queue_);
    push_descriptor_ = reinterpret_cast<PFN_vkCmdPushDescriptorSetKHR>(
        vkGetDeviceProcAddr(device_, "vkCmdPushDescriptorSetKHR"));
    if (!push_descriptor_)
      throw Error("vkCmdPushDescriptorSetKHR is missing although the extension is enabled");

    // Pipeline cache, seeded from the file when it was written for this device and driver.
    cache_path_ = options.pipeline_cache;
    std::vector<char> cache_data;
    if (!cache_path_.empty()) {
      std::ifstream in(cache_path_, std::ios::binary);
      if (in) cache_data.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
      if (!cache_matches(cache_data, props_)) cache_data.clear();
    }
    auto cinfo = vk_struct<VkPipelineCacheCreateInfo>(VK_STRUCTURE_TYPE_PIPELINE_CACHE_CREATE_INFO);
    cinfo.initialDataSize = cache_data.size();
    cinfo.pInitialData = cache_data.empty() ? nullptr : cache_data.data();
    HAZE_VK(vkCreatePipelineCache(device_, &cinfo, nullptr, &pipeline_cache_));

    auto pinfo = vk_struct<VkCommandPoolCreateInfo>(VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO);
    pinfo.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pinfo.queueFamilyIndex = family_;
    HAZE_VK(vkCreateCommandPool(device_, &pinfo, nullptr, &pool_));
    auto ainfo = vk_struct<VkCommandBufferAllocateInfo>(VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO);
    ainfo.commandPool = pool_;
    ainfo.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    ainfo.commandBufferCount = 1;
    HAZE_VK(vkAllocateCommandBuffers(device_, &ainfo, &cmd_));
    auto finfo = vk_struct<VkFenceCreateInfo>(VK_STRUCTURE_TYPE_FENCE_CREATE_INFO);
    HAZE_VK(vkCreateFence(device_, &finfo, nullptr, &fence_));
  } catch (...) {
    destroy();
    throw;
  }
}

Context::~Context() {
  if (device_) vkDeviceWaitIdle(device_);
  try {
    save_pipeline_cache();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "haze: %s\n", e.what());
  }
  auto live = ledger_.entries();
  if (!live.empty())
    std::fprintf(stderr, "haze: gpu context destroyed with %zu live allocations (first: '%s')\n", live.size(),
                 live.front().name.c_str());
  destroy();
}

void Context::destroy() noexcept {
  if (device_) {
    vkDeviceWaitIdle(device_);
    if (kernels_) kernels_->clear();
    if (fence_) vkDestroyFence(device_, fence_, nullptr);
    if (pool_) vkDestroyCommandPool(device_, pool_, nullptr);
    if (pipeline_cache_) vkDestroyPipelineCache(device_, pipeline_cache_, nullptr);
    vkDestroyDevice(device_, nullptr);
  }
  fence_ = VK_NULL_HANDLE;
  pool_ = VK_NULL_HANDLE;
  pipeline_cache_ = VK_NULL_HANDLE;
  device_ = VK_NULL_HANDLE;
  if (instance_) {
    if (messenger_) {
      auto destroy_fn = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
          vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
      if (destroy_fn) destroy_fn(instance_, messenger_, nullptr);
    }
    vkDestroyInstance(instance_, nullptr);
  }
  messenger_ = VK_NULL_HANDLE;
  instance_ = VK_NULL_HANDLE;
}

void Context::save_pipeline_cache() const {
  if (cache_path_.empty() || !pipeline_cache_) return;
  size_t size = 0;
  HAZE_VK(vkGetPipelineCacheData(device_, pipeline_cache_, &size, nullptr));
  std::vector<char> data(size);
  HAZE_VK(vkGetPipelineCacheData(device_, pipeline_cache_, &size, data.data()));
  data.resize(size);
  // tmp + rename: a crash or a parallel process never leaves a half-written cache behind.
  std::string tmp = fmt::format("{}.tmp.{}", cache_path_, static_cast<long>(::getpid()));
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(data.data(), static_cast<std::streamsize>(data.size()));
    if (!out) throw Error(fmt::format("cannot write pipeline cache '{}'", tmp));
  }
  std::error_code ec;
  std::filesystem::rename(tmp, cache_path_, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw Error(fmt::format("cannot write pipeline cache '{}': {}", cache_path_, ec.message()));
  }
}

void Context::set_object_name(VkObjectType type, uint64_t handle, const std::string& name) const {
  if (!set_name_ || !device_ || !handle) return;
  auto info = vk_struct<VkDebugUtilsObjectNameInfoEXT>(VK_STRUCTURE_TYPE_DEBUG_UTILS_OBJECT_NAME_INFO_EXT);
  info.objectType = type;
  info.objectHandle = handle;
  info.pObjectName = name.c_str();
  set_name_(device_, &info);
}

std::string Context::driver_info() const {
  if (driver_.driverName[0] == 0) return api_string(props_.driverVersion);
  return driver_.driverInfo[0] ? fmt::format("{} {}", driver_.driverName, driver_.driverInfo)
                               : std::string(driver_.driverName);
}

bool Context::is_cpu() const {
  return props_.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU || driver_.driverID == VK_DRIVER_ID_MESA_LLVMPIPE;
}

nlohmann::json Context::describe() const {
  return {{"name", name_},
          {"type", type_name(props_.deviceType)},
          {"driver", driver_info()},
          {"api_version", api_string(props_.apiVersion)},
          {"index", index_},
          {"vendor_id", props_.vendorID},
          {"device_id", props_.deviceID},
          {"validation", validation_enabled()},
          {"subgroup_size", features_.subgroup_size},
          {"timestamp_period_ns", props_.limits.timestampPeriod},
          {"max_storage_buffer_range", props_.limits.maxStorageBufferRange},
          {"max_allocation_size", max_allocation_},
          {"features",
           {{"int64", features_.int64},
            {"float64", features_.float64},
            {"int16", features_.int16},
            {"int8", features_.int8},
            {"float16", features_.float16},
            {"storage_8bit", features_.storage_8bit},
            {"storage_16bit", features_.storage_16bit},
            {"scalar_layout", features_.scalar_layout},
            {"buffer_device_address", features_.buffer_device_address},
            {"buffer_int64_atomics", features_.buffer_int64_atomics},
            {"atomic_float_add", features_.atomic_float_add},
            {"subgroup_size_control", features_.subgroup_size_control},
            {"subgroup_arithmetic", features_.subgroup_arithmetic},
            {"timestamps", features_.timestamps}}}};
}

void Context::submit_and_wait(const std::function<void(VkCommandBuffer)>& record) {
  std::lock_guard lock(submit_mutex_);
  if (recording_)
    throw Error(
        "submit_and_wait called from inside its own recording callback (nested submissions are not "
        "supported)");
  recording_ = true;
  struct Reset {
    bool& flag;
    ~Reset() { flag = false; }
  } reset{recording_};

  // A buffer left half-recorded by a throwing callback is reset here, before reuse.
  HAZE_VK(vkResetCommandBuffer(cmd_, 0));
  auto begin = vk_struct<VkCommandBufferBeginInfo>(VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO);
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  HAZE_VK(vkBeginCommandBuffer(cmd_, &begin));
  record(cmd_);
  // Make every device write visible to host reads (mapped buffers) and to the next submission's commands.
  auto after = vk_struct<VkMemoryBarrier>(VK_STRUCTURE_TYPE_MEMORY_BARRIER);
  after.srcAccessMask = VK_ACCESS_MEMORY_WRITE_BIT;
  after.dstAccessMask = VK_ACCESS_HOST_READ_BIT | VK_ACCESS_MEMORY_READ_BIT | VK_ACCESS_MEMORY_WRITE_BIT;
  vkCmdPipelineBarrier(cmd_, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                       VK_PIPELINE_STAGE_HOST_BIT | VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, 1, &after, 0,
                       nullptr, 0, nullptr);
  HAZE_VK(vkEndCommandBuffer(cmd_));

  HAZE_VK(vkResetFences(device_, 1, &fence_));
  auto submit = vk_struct<VkSubmitInfo>(VK_STRUCTURE_TYPE_SUBMIT_INFO);
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cmd_;
  HAZE_VK(vkQueueSubmit(queue_, 1, &submit, fence_));
  HAZE_VK(vkWaitForFences(device_, 1, &fence_, VK_TRUE, UINT64_MAX));
}

void Context::submit(const VkSubmitInfo& info, VkFence fence) {
  std::lock_guard lock(submit_mutex_);
  HAZE_VK(vkQueueSubmit(queue_, 1, &info, fence));
}

VkResult Context::present(const VkPresentInfoKHR& info) {
  std::lock_guard lock(submit_mutex_);
  return vkQueuePresentKHR(queue_, &info);
}

void Context::track_in_flight(VkFence fence) {
  std::lock_guard lock(in_flight_mutex_);
  in_flight_.push_back(fence);
}

void Context::untrack_in_flight(VkFence fence) {
  std::lock_guard lock(in_flight_mutex_);
  in_flight_.erase(std::remove(in_flight_.begin(), in_flight_.end(), fence), in_flight_.end());
}

void Context::wait_in_flight() {
  std::lock_guard lock(in_flight_mutex_);
  bool waited = false;
  for (VkFence f : in_flight_) {
    if (vkGetFenceStatus(device_, f) == VK_SUCCESS) continue;
    HAZE_VK(vkWaitForFences(device_, 1, &f, VK_TRUE, UINT64_MAX));
    waited = true;
  }
  if (waited) host_waits_.fetch_add(1);
}

std::vector<nlohmann::json> list_devices() {
  VkInstance instance = create_instance({}, {}, nullptr);
  std::vector<nlohmann::json> out;
  try {
    for (const auto& c : enumerate(instance)) out.push_back(candidate_json(c));
  } catch (...) {
    vkDestroyInstance(instance, nullptr);
    throw;
  }
  vkDestroyInstance(instance, nullptr);
  return out;
}

}  // namespace haze::gpu
