#include "gpu/pipeline.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <map>
#include <utility>

#include "gpu/buffer.hpp"
#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/image.hpp"
#include "gpu/vk_struct.hpp"

namespace haze::gpu {
namespace {

constexpr uint32_t kSpirvMagic = 0x07230203;
constexpr uint32_t kMaxPushBytes = 128;
constexpr uint32_t kMaxPushDescriptors = 32;  // the guaranteed minimum of maxPushDescriptors

// What the shader does with a binding, as far as the pipeline's slots are concerned.
enum class Use { Unknown, Buffer, Image, Other };

struct BindingUse {
  uint32_t set = 0, binding = 0;
  Use use = Use::Unknown;
  const char* what = "";      // for messages: "storage buffer", "uniform buffer", ...
  bool plain_2d = true;       // storage images: 2D, not arrayed, not multisampled
  uint32_t image_format = 0;  // storage images: SPIR-V ImageFormat (0 = Unknown, i.e. none declared)
};

// What the pipeline needs to know from the module, read straight from the SPIR-V words.
struct Reflection {
  std::array<uint32_t, 3> local_size{0, 0, 0};
  std::vector<BindingUse> bindings;
  bool push_constants = false;
};

Reflection reflect(const std::vector<uint32_t>& words, const std::vector<uint32_t>& spec) {
  enum : uint32_t {
    kOpExecutionMode = 16,
    kOpExecutionModeId = 331,
    kOpConstant = 43,
    kOpConstantComposite = 44,
    kOpSpecConstant = 50,
    kOpSpecConstantComposite = 51,
    kOpTypeImage = 25,
    kOpTypeSampler = 26,
    kOpTypeSampledImage = 27,
    kOpTypeArray = 28,
    kOpTypeRuntimeArray = 29,
    kOpTypePointer = 32,
    kOpVariable = 59,
    kOpDecorate = 71,
    kModeLocalSize = 17,
    kModeLocalSizeId = 38,
    kDecSpecId = 1,
    kDecBlock = 2,
    kDecBufferBlock = 3,
    kDecBuiltIn = 11,
    kDecBinding = 33,
    kDecSet = 34,
    kBuiltInWorkgroupSize = 25,
    kStorageUniform = 2,
    kStoragePushConstant = 9,
    kStorageStorageBuffer = 12,
    kDim2D = 1,
    kDimBuffer = 5,
    kSampledStorage = 2,  // OpTypeImage "Sampled" operand: used without a sampler
  };
  Reflection r;
  std::map<uint32_t, uint32_t> value, spec_id, set, binding;
  std::map<uint32_t, std::vector<uint32_t>> composite;
  std::map<uint32_t, uint32_t> block_decoration, element, var_pointer;
  std::map<uint32_t, std::pair<uint32_t, uint32_t>> pointer;  // id -> (storage class, pointee)
  std::map<uint32_t, std::vector<uint32_t>> image;            // id -> OpTypeImage words
  std::map<uint32_t, uint32_t> other_type;                    // sampler / sampled image ids -> opcode
  uint32_t wg_size_id = 0;
  std::vector<uint32_t> local_ids;  // LocalSizeId operands (SPIR-V >= 1.2)
  for (size_t i = 5; i < words.size();) {
    uint32_t op = words[i] & 0xffff, n = words[i] >> 16;
    if (n == 0 || i + n > words.size()) break;
    const uint32_t* w = &words[i];
    if (op == kOpExecutionMode && n >= 6 && w[2] == kModeLocalSize) {
      r.local_size = {w[3], w[4], w[5]};
    } else if (op == kOpExecutionModeId && n >= 6 && w[2] == kModeLocalSizeId) {
      local_ids.assign(w + 3, w + 6);
    } else if ((op == kOpConstant || op == kOpSpecConstant) && n >= 4) {
      value[w[2]] = w[3];
    } else if ((op == kOpConstantComposite || op == kOpSpecConstantComposite) && n >= 3) {
      composite[w[2]].assign(w + 3, w + n);
    } else if (op == kOpTypeImage && n >= 9) {
      image[w[1]].assign(w, w + n);
    } else if ((op == kOpTypeSampler || op == kOpTypeSampledImage) && n >= 2) {
      other_type[w[1]] = op;
    } else if ((op == kOpTypeArray || op == kOpTypeRuntimeArray) && n >= 3) {
      element[w[1]] = w[2];
    } else if (op == kOpTypePointer && n >= 4) {
      pointer[w[1]] = {w[2], w[3]};
    } else if (op == kOpVariable && n >= 4) {
      if (w[3] == kStoragePushConstant) r.push_constants = true;
      var_pointer[w[2]] = w[1];
    } else if (op == kOpDecorate && n >= 3 && (w[2] == kDecBlock || w[2] == kDecBufferBlock)) {
      block_decoration[w[1]] = w[2];
    } else if (op == kOpDecorate && n >= 4) {
      if (w[2] == kDecSpecId) spec_id[w[1]] = w[3];
      if (w[2] == kDecBinding) binding[w[1]] = w[3];
      if (w[2] == kDecSet) set[w[1]] = w[3];
      if (w[2] == kDecBuiltIn && w[3] == kBuiltInWorkgroupSize) wg_size_id = w[1];
    }
    i += n;
  }
  for (const auto& [id, b] : binding) {
    BindingUse u;
    u.set = set.count(id) ? set[id] : 0;
    u.binding = b;
    auto vp = var_pointer.find(id);
    auto ptr = vp != var_pointer.end() ? pointer.find(vp->second) : pointer.end();
    if (ptr != pointer.end()) {
      auto [storage, type] = ptr->second;
      while (element.count(type)) type = element[type];  // arrays of descriptors: classify the element
      if (auto im = image.find(type); im != image.end()) {
        // [1] result, [2] sampled type, [3] Dim, [4] Depth, [5] Arrayed, [6] MS, [7] Sampled, [8] Format
        const auto& iw = im->second;
        if (iw[3] == kDimBuffer) {
          u.use = Use::Other;
          u.what = iw[7] == kSampledStorage ? "storage texel buffer" : "uniform texel buffer";
        } else if (iw[7] == kSampledStorage) {
          u.use = Use::Image;
          u.what = "storage image";
          u.plain_2d = iw[3] == kDim2D && iw[5] == 0 && iw[6] == 0;
          u.image_format = iw[8];
        } else {
          u.use = Use::Other;
          u.what = "sampled image";
        }
      } else if (other_type.count(type)) {
        u.use = Use::Other;
        u.what = other_type[type] == kOpTypeSampler ? "sampler" : "combined image sampler";
      } else if (storage == kStorageStorageBuffer ||
                 (storage == kStorageUniform && block_decoration[type] == kDecBufferBlock)) {
        u.use = Use::Buffer;
        u.what = "storage buffer";
      } else if (storage == kStorageUniform) {
        u.use = Use::Other;
        u.what = "uniform buffer";
      }
    }
    r.bindings.push_back(u);
  }
  // The value of a (possibly specialized) constant id.
  const auto resolve = [&](uint32_t id) -> uint32_t {
    auto s = spec_id.find(id);
    if (s != spec_id.end() && s->second < spec.size()) return spec[s->second];
    auto v = value.find(id);
    return v != value.end() ? v->second : 0;
  };
  if (local_ids.size() == 3)
    for (int k = 0; k < 3; ++k) r.local_size[k] = resolve(local_ids[k]);
  // A WorkgroupSize built-in overrides both execution modes.
  if (wg_size_id && composite.count(wg_size_id) && composite[wg_size_id].size() == 3)
    for (int k = 0; k < 3; ++k) r.local_size[k] = resolve(composite[wg_size_id][k]);
  return r;
}

// SPIR-V ImageFormat -> the gpu::Image format it must be bound with (Vulkan's compatibility table).
constexpr std::pair<uint32_t, VkFormat> kSpirvImageFormats[] = {
    {1, VK_FORMAT_R32G32B32A32_SFLOAT},      // Rgba32f
    {2, VK_FORMAT_R16G16B16A16_SFLOAT},      // Rgba16f
    {3, VK_FORMAT_R32_SFLOAT},               // R32f
    {4, VK_FORMAT_R8G8B8A8_UNORM},           // Rgba8
    {6, VK_FORMAT_R32G32_SFLOAT},            // Rg32f
    {7, VK_FORMAT_R16G16_SFLOAT},            // Rg16f
    {8, VK_FORMAT_B10G11R11_UFLOAT_PACK32},  // R11fG11fB10f
    {9, VK_FORMAT_R16_SFLOAT},               // R16f
    {24, VK_FORMAT_R32_SINT},                // R32i
    {33, VK_FORMAT_R32_UINT},                // R32ui
};

VkFormat vk_format(uint32_t spirv_format) {
  for (auto [spv, vk] : kSpirvImageFormats)
    if (spv == spirv_format) return vk;
  return VK_FORMAT_UNDEFINED;
}

VkDescriptorType descriptor_type(Slot s) {
  return s == Slot::Buffer ? VK_DESCRIPTOR_TYPE_STORAGE_BUFFER : VK_DESCRIPTOR_TYPE_STORAGE_IMAGE;
}

const char* slot_name(Slot s) {
  return s == Slot::Buffer ? "storage buffer" : "storage image";
}

// The (num_buffers) constructor's slots; refuses absurd counts before allocating them.
std::vector<Slot> buffer_slots(const std::string& path, uint32_t num_buffers) {
  if (num_buffers > kMaxPushDescriptors)
    throw Error(fmt::format("pipeline '{}': {} buffers, at most {} can be pushed", path, num_buffers,
                            kMaxPushDescriptors));
  return std::vector<Slot>(num_buffers, Slot::Buffer);
}

}  // namespace

std::vector<uint32_t> read_spirv(const std::string& path) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw Error(fmt::format("cannot open SPIR-V file '{}': {}", path, std::strerror(errno)));
  auto size = static_cast<uint64_t>(in.tellg());
  if (size < 20 || size % 4 != 0)
    throw Error(fmt::format(
        "'{}' is not a SPIR-V module ({} bytes, expected a multiple of 4 and at least 20)", path, size));
  std::vector<uint32_t> words(size / 4);
  in.seekg(0);
  if (!in.read(reinterpret_cast<char*>(words.data()), static_cast<std::streamsize>(size)))
    throw Error(fmt::format("cannot read SPIR-V file '{}'", path));
  if (words[0] != kSpirvMagic)
    throw Error(fmt::format("'{}' is not a SPIR-V module (magic number {:#010x}, expected {:#010x})", path,
                            words[0], kSpirvMagic));
  return words;
}

void compute_barrier(VkCommandBuffer cmd) {
  auto b = vk_struct<VkMemoryBarrier>(VK_STRUCTURE_TYPE_MEMORY_BARRIER);
  b.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  b.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_READ_BIT |
                    VK_ACCESS_TRANSFER_WRITE_BIT;
  constexpr VkPipelineStageFlags stages =
      VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT;
  vkCmdPipelineBarrier(cmd, stages, stages, 0, 1, &b, 0, nullptr, 0, nullptr);
}

ComputePipeline::ComputePipeline(Context& ctx, const std::string& spv_path, uint32_t num_buffers,
                                 uint32_t push_bytes, const std::vector<uint32_t>& spec_constants)
    : ComputePipeline(ctx, spv_path, buffer_slots(spv_path, num_buffers), push_bytes, spec_constants) {}

ComputePipeline::ComputePipeline(Context& ctx, const std::string& spv_path, std::vector<Slot> slots,
                                 uint32_t push_bytes, const std::vector<uint32_t>& spec_constants)
    : ctx_(&ctx), path_(spv_path), slots_(std::move(slots)), push_bytes_(push_bytes) {
  check_layout();
  create(read_spirv(spv_path), spec_constants);
}

ComputePipeline::ComputePipeline(Context& ctx, std::string name, const std::vector<uint32_t>& spirv,
                                 std::vector<Slot> slots, uint32_t push_bytes,
                                 const std::vector<uint32_t>& spec_constants)
    : ctx_(&ctx), path_(std::move(name)), slots_(std::move(slots)), push_bytes_(push_bytes) {
  check_layout();
  if (spirv.size() < 5 || spirv[0] != kSpirvMagic)
    throw Error(fmt::format("'{}' is not a SPIR-V module ({} words)", path_, spirv.size()));
  create(spirv, spec_constants);
}

void ComputePipeline::check_layout() const {
  const Context& ctx = *ctx_;
  uint32_t max_push = std::min(kMaxPushBytes, ctx.limits().maxPushConstantsSize);
  if (push_bytes_ % 4 != 0 || push_bytes_ > max_push)
    throw Error(fmt::format("pipeline '{}': push constants of {} bytes (must be a multiple of 4, at most {})",
                            path_, push_bytes_, max_push));
  const auto num_slots = static_cast<uint32_t>(slots_.size());
  if (num_slots > kMaxPushDescriptors)
    throw Error(fmt::format("pipeline '{}': {} bindings, at most {} can be pushed", path_, num_slots,
                            kMaxPushDescriptors));
  const auto num_images = static_cast<uint32_t>(std::count(slots_.begin(), slots_.end(), Slot::Image));
  if (num_images > ctx.limits().maxPerStageDescriptorStorageImages)
    throw Error(fmt::format("pipeline '{}': {} storage images, this device allows {} per shader stage", path_,
                            num_images, ctx.limits().maxPerStageDescriptorStorageImages));
}

void ComputePipeline::create(const std::vector<uint32_t>& words,
                             const std::vector<uint32_t>& spec_constants) {
  Context& ctx = *ctx_;
  const uint32_t push_bytes = push_bytes_;
  const auto num_slots = static_cast<uint32_t>(slots_.size());
  Reflection refl = reflect(words, spec_constants);
  image_formats_.assign(num_slots, VK_FORMAT_UNDEFINED);
  for (const BindingUse& u : refl.bindings) {
    if (u.set != 0 || u.binding >= num_slots)
      throw Error(fmt::format(
          "pipeline '{}': the shader uses set {} binding {}, but the pipeline declares {} bindings in set 0",
          path_, u.set, u.binding, num_slots));
    Slot slot = slots_[u.binding];
    if (u.use == Use::Other || (u.use == Use::Buffer && slot != Slot::Buffer) ||
        (u.use == Use::Image && slot != Slot::Image))
      throw Error(
          fmt::format("pipeline '{}': the shader uses binding {} as a {}, but the pipeline declares a {}",
                      path_, u.binding, u.what, slot_name(slot)));
    if (u.use == Use::Image && !u.plain_2d)
      throw Error(fmt::format(
          "pipeline '{}': binding {} is not a plain 2D storage image (arrayed, multisampled or not 2D); "
          "gpu::Image binds image2D only",
          path_, u.binding));
    if (u.use == Use::Image && u.image_format != 0) {  // 0: no format declared, any image will do
      image_formats_[u.binding] = vk_format(u.image_format);
      if (image_formats_[u.binding] == VK_FORMAT_UNDEFINED)
        throw Error(
            fmt::format("pipeline '{}': binding {} declares SPIR-V image format {}, which no gpu::Image "
                        "format matches",
                        path_, u.binding, u.image_format));
    }
  }
  if (refl.push_constants && push_bytes == 0)
    throw Error(fmt::format("pipeline '{}': the shader has push constants but push_bytes is 0", path_));
  local_size_ = refl.local_size;

  VkDevice dev = ctx.device();
  VkShaderModule module = VK_NULL_HANDLE;
  try {
    std::vector<VkDescriptorSetLayoutBinding> bindings(num_slots);
    for (uint32_t i = 0; i < num_slots; ++i)
      bindings[i] = {i, descriptor_type(slots_[i]), 1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr};
    auto sinfo =
        vk_struct<VkDescriptorSetLayoutCreateInfo>(VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO);
    sinfo.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_PUSH_DESCRIPTOR_BIT_KHR;
    sinfo.bindingCount = num_slots;
    sinfo.pBindings = bindings.data();
    HAZE_VK(vkCreateDescriptorSetLayout(dev, &sinfo, nullptr, &set_layout_));

    VkPushConstantRange range{VK_SHADER_STAGE_COMPUTE_BIT, 0, push_bytes};
    auto linfo = vk_struct<VkPipelineLayoutCreateInfo>(VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO);
    linfo.setLayoutCount = 1;
    linfo.pSetLayouts = &set_layout_;
    linfo.pushConstantRangeCount = push_bytes ? 1 : 0;
    linfo.pPushConstantRanges = push_bytes ? &range : nullptr;
    HAZE_VK(vkCreatePipelineLayout(dev, &linfo, nullptr, &layout_));

    auto minfo = vk_struct<VkShaderModuleCreateInfo>(VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO);
    minfo.codeSize = words.size() * 4;
    minfo.pCode = words.data();
    vk_check(vkCreateShaderModule(dev, &minfo, nullptr, &module),
             fmt::format("vkCreateShaderModule('{}')", path_));

    std::vector<VkSpecializationMapEntry> entries(spec_constants.size());
    for (uint32_t i = 0; i < entries.size(); ++i) entries[i] = {i, i * 4, 4};
    VkSpecializationInfo spec{static_cast<uint32_t>(entries.size()), entries.data(),
                              spec_constants.size() * 4, spec_constants.data()};
    auto pinfo = vk_struct<VkComputePipelineCreateInfo>(VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO);
    pinfo.stage =
        vk_struct<VkPipelineShaderStageCreateInfo>(VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO);
    pinfo.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
    pinfo.stage.module = module;
    pinfo.stage.pName = "main";
    pinfo.stage.pSpecializationInfo = spec_constants.empty() ? nullptr : &spec;
    pinfo.layout = layout_;
    auto t0 = std::chrono::steady_clock::now();
    VkResult r = vkCreateComputePipelines(dev, ctx.pipeline_cache(), 1, &pinfo, nullptr, &pipeline_);
    creation_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    vk_check(r, fmt::format("vkCreateComputePipelines('{}')", path_));
    ctx.set_object_name(VK_OBJECT_TYPE_PIPELINE, reinterpret_cast<uint64_t>(pipeline_), path_);
    vkDestroyShaderModule(dev, module, nullptr);
  } catch (...) {
    if (module) vkDestroyShaderModule(dev, module, nullptr);
    release();
    throw;
  }
}

void ComputePipeline::release() noexcept {
  if (!ctx_) return;
  VkDevice dev = ctx_->device();
  if (pipeline_) vkDestroyPipeline(dev, pipeline_, nullptr);
  if (layout_) vkDestroyPipelineLayout(dev, layout_, nullptr);
  if (set_layout_) vkDestroyDescriptorSetLayout(dev, set_layout_, nullptr);
  pipeline_ = VK_NULL_HANDLE;
  layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
  ctx_ = nullptr;
}

ComputePipeline::~ComputePipeline() {
  release();
}

ComputePipeline::ComputePipeline(ComputePipeline&& o) noexcept
    : ctx_(std::exchange(o.ctx_, nullptr)),
      set_layout_(std::exchange(o.set_layout_, VK_NULL_HANDLE)),
      layout_(std::exchange(o.layout_, VK_NULL_HANDLE)),
      pipeline_(std::exchange(o.pipeline_, VK_NULL_HANDLE)),
      path_(std::move(o.path_)),
      slots_(std::move(o.slots_)),
      image_formats_(std::move(o.image_formats_)),
      push_bytes_(o.push_bytes_),
      creation_ms_(o.creation_ms_),
      local_size_(o.local_size_) {}

ComputePipeline& ComputePipeline::operator=(ComputePipeline&& o) noexcept {
  if (this != &o) {
    release();
    ctx_ = std::exchange(o.ctx_, nullptr);
    set_layout_ = std::exchange(o.set_layout_, VK_NULL_HANDLE);
    layout_ = std::exchange(o.layout_, VK_NULL_HANDLE);
    pipeline_ = std::exchange(o.pipeline_, VK_NULL_HANDLE);
    path_ = std::move(o.path_);
    slots_ = std::move(o.slots_);
    image_formats_ = std::move(o.image_formats_);
    push_bytes_ = o.push_bytes_;
    creation_ms_ = o.creation_ms_;
    local_size_ = o.local_size_;
  }
  return *this;
}

uint32_t ComputePipeline::num_buffers() const {
  return static_cast<uint32_t>(std::count(slots_.begin(), slots_.end(), Slot::Buffer));
}

void ComputePipeline::dispatch(VkCommandBuffer cmd, std::initializer_list<const Buffer*> buffers,
                               const void* push, uint32_t gx, uint32_t gy, uint32_t gz) const {
  dispatch(cmd, std::span<const Buffer* const>(buffers.begin(), buffers.size()), push, gx, gy, gz);
}

void ComputePipeline::dispatch(VkCommandBuffer cmd, std::span<const Buffer* const> buffers, const void* push,
                               uint32_t gx, uint32_t gy, uint32_t gz) const {
  std::vector<Resource> resources(buffers.begin(), buffers.end());
  dispatch(cmd, std::span<const Resource>(resources), push, gx, gy, gz);
}

void ComputePipeline::dispatch(VkCommandBuffer cmd, std::span<const Resource> resources, const void* push,
                               uint32_t gx, uint32_t gy, uint32_t gz) const {
  if (!pipeline_) throw Error("dispatch of an empty gpu::ComputePipeline");
  if (resources.size() != slots_.size())
    throw Error(fmt::format("dispatch of '{}' with {} resources, the pipeline declares {} bindings", path_,
                            resources.size(), slots_.size()));
  const auto& limits = ctx_->limits();
  // Sized up front: the writes point into these.
  std::vector<VkDescriptorBufferInfo> buffer_infos(resources.size());
  std::vector<VkDescriptorImageInfo> image_infos(resources.size());
  std::vector<VkWriteDescriptorSet> writes(resources.size());
  for (uint32_t i = 0; i < resources.size(); ++i) {
    const Resource& res = resources[i];
    writes[i] = vk_struct<VkWriteDescriptorSet>(VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET);
    writes[i].dstBinding = i;
    writes[i].descriptorCount = 1;
    writes[i].descriptorType = descriptor_type(slots_[i]);
    if (slots_[i] == Slot::Buffer) {
      if (res.image)
        throw Error(fmt::format("dispatch of '{}': binding {} is a storage buffer, but got image '{}'", path_,
                                i, res.image->name()));
      const Buffer* b = res.buffer;
      if (!b || !b->valid()) throw Error(fmt::format("dispatch of '{}': buffer {} is empty", path_, i));
      if (b->size() > limits.maxStorageBufferRange)
        throw Error(fmt::format(
            "dispatch of '{}': buffer '{}' ({}) is larger than this device's maxStorageBufferRange "
            "({}); reach it through its device address",
            path_, b->name(), format_bytes(b->size()), format_bytes(limits.maxStorageBufferRange)));
      buffer_infos[i] = {b->handle(), 0, VK_WHOLE_SIZE};
      writes[i].pBufferInfo = &buffer_infos[i];
    } else {
      if (res.buffer)
        throw Error(fmt::format("dispatch of '{}': binding {} is a storage image, but got buffer '{}'", path_,
                                i, res.buffer->name()));
      const Image* im = res.image;
      if (!im || !im->valid()) throw Error(fmt::format("dispatch of '{}': image {} is empty", path_, i));
      VkFormat want = image_formats_[i];
      if (want != VK_FORMAT_UNDEFINED && im->format() != want)
        throw Error(
            fmt::format("dispatch of '{}': binding {} is declared {} in the shader, but image '{}' is {}",
                        path_, i, image_format_name(want), im->name(), im->format_name()));
      image_infos[i] = {VK_NULL_HANDLE, im->view(), VK_IMAGE_LAYOUT_GENERAL};
      writes[i].pImageInfo = &image_infos[i];
    }
  }
  if (push_bytes_ && !push)
    throw Error(fmt::format("dispatch of '{}' without its {} bytes of push constants", path_, push_bytes_));
  const uint32_t* maxg = limits.maxComputeWorkGroupCount;
  if (gx > maxg[0] || gy > maxg[1] || gz > maxg[2])
    throw Error(fmt::format("dispatch of '{}' with {}x{}x{} groups exceeds the device limit {}x{}x{}", path_,
                            gx, gy, gz, maxg[0], maxg[1], maxg[2]));
  vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline_);
  if (!writes.empty())
    ctx_->cmd_push_descriptor_set()(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, layout_, 0,
                                    static_cast<uint32_t>(writes.size()), writes.data());
  if (push_bytes_) vkCmdPushConstants(cmd, layout_, VK_SHADER_STAGE_COMPUTE_BIT, 0, push_bytes_, push);
  vkCmdDispatch(cmd, gx, gy, gz);
}

}  // namespace haze::gpu
