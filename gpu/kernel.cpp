#include "gpu/kernel.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <chrono>

#include "gpu/buffer.hpp"
#include "gpu/context.hpp"
#include "gpu/error.hpp"
#include "gpu/image.hpp"

namespace haze::gpu {
namespace {

bool is_identifier(std::string_view s) {
  if (s.empty() || !(std::isalpha(static_cast<unsigned char>(s[0])) || s[0] == '_')) return false;
  return std::all_of(s.begin(), s.end(),
                     [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_'; });
}

}  // namespace

KernelDecl::KernelDecl(std::string source) : source_(std::move(source)) {}

KernelDecl& KernelDecl::define(const std::string& name, const std::string& value) {
  if (!is_identifier(name))
    throw Error(fmt::format("kernel {}: define '{}' is not an identifier", source_, name));
  for (auto& d : defines_)
    if (d.first == name) {
      d.second = value;
      return *this;
    }
  defines_.emplace_back(name, value);
  return *this;
}

KernelDecl& KernelDecl::buffer(const std::string& name, uint64_t min_bytes, uint64_t element_bytes) {
  if (!is_identifier(name))
    throw Error(fmt::format("kernel {}: binding '{}' is not an identifier", source_, name));
  for (auto& b : bindings_)
    if (b.name == name) {
      if (b.slot != Slot::Buffer)
        throw Error(fmt::format("{}: binding '{}' declared as an image and a buffer", describe(), name));
      b.min_bytes = std::max(b.min_bytes, min_bytes);
      if (element_bytes) b.element_bytes = element_bytes;
      return *this;
    }
  bindings_.push_back({name, Slot::Buffer, min_bytes, element_bytes});
  return *this;
}

KernelDecl& KernelDecl::image(const std::string& name) {
  if (!is_identifier(name))
    throw Error(fmt::format("kernel {}: binding '{}' is not an identifier", source_, name));
  for (auto& b : bindings_)
    if (b.name == name) {
      if (b.slot != Slot::Image)
        throw Error(fmt::format("{}: binding '{}' declared as a buffer and an image", describe(), name));
      return *this;
    }
  bindings_.push_back({name, Slot::Image, 0, 0});
  return *this;
}

KernelDecl& KernelDecl::push(uint32_t bytes) {
  push_bytes_ = bytes;
  return *this;
}

KernelDecl& KernelDecl::specialize(std::vector<uint32_t> values) {
  spec_ = std::move(values);
  return *this;
}

bool KernelDecl::defined(std::string_view name) const {
  return std::any_of(defines_.begin(), defines_.end(), [&](const auto& d) { return d.first == name; });
}

bool KernelDecl::binds(std::string_view name) const {
  return std::any_of(bindings_.begin(), bindings_.end(),
                     [&](const BindingDecl& b) { return b.name == name; });
}

std::string KernelDecl::label() const {
  std::string s = ShaderCompiler::label(ShaderPermutation{source_, defines_, {}});
  if (!spec_.empty()) s += fmt::format(" spec {}", fmt::join(spec_, ","));
  return s;
}

ShaderPermutation KernelDecl::permutation() const {
  ShaderPermutation p;
  p.source = source_;
  p.defines = defines_;
  for (size_t i = 0; i < bindings_.size(); ++i)
    p.defines.emplace_back("BINDING_" + bindings_[i].name, std::to_string(i));
  p.label = label();
  return p;
}

std::string KernelDecl::pipeline_key() const {
  std::string k = source_;
  for (const auto& [name, value] : defines_) k += fmt::format(" -D{}={}", name, value);
  for (const auto& b : bindings_)
    k += fmt::format(" {}:{}", b.slot == Slot::Buffer ? "buffer" : "image", b.name);
  k += fmt::format(" push {} spec {}", push_bytes_, fmt::join(spec_, ","));
  return k;
}

std::string KernelDecl::describe() const {
  return fmt::format("kernel {} [{}]", source_, label());
}

Bindings& Bindings::set(const std::string& name, const Buffer& b) {
  resources_.insert_or_assign(name, Resource(&b));
  return *this;
}

Bindings& Bindings::set(const std::string& name, const Image& i) {
  resources_.insert_or_assign(name, Resource(&i));
  return *this;
}

const Resource* Bindings::find(const std::string& name) const {
  auto it = resources_.find(name);
  return it == resources_.end() ? nullptr : &it->second;
}

void require_strided(const Buffer& b, uint64_t items, uint32_t stride, uint32_t offset, uint32_t n,
                     const std::string& who, const char* what) {
  if (items == 0) return;
  if (stride < offset + n || b.size() < ((items - 1) * stride + offset + n) * 4)
    throw Error(
        fmt::format("{}: {} buffer '{}' ({} bytes) does not hold {} records of {} floats with {} at {}", who,
                    what, b.name(), b.size(), items, stride, n, offset));
}

const ComputePipeline& KernelCache::get(const KernelDecl& decl, double* setup_ms) {
  if (setup_ms) *setup_ms = 0;
  const std::string key = decl.pipeline_key();
  std::lock_guard lock(mutex_);
  auto& p = pipelines_[key];
  if (!p) {
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<uint32_t> words;
    try {
      words = ctx_.shaders().compile(decl.permutation());
    } catch (...) {
      pipelines_.erase(key);
      throw;
    }
    std::vector<Slot> slots;
    for (const auto& b : decl.bindings()) slots.push_back(b.slot);
    try {
      p = std::make_unique<ComputePipeline>(ctx_, fmt::format("{} [{}]", decl.source(), decl.label()), words,
                                            std::move(slots), decl.push_bytes(), decl.spec());
    } catch (...) {
      pipelines_.erase(key);
      throw;
    }
    if (setup_ms)
      *setup_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  return *p;
}

size_t KernelCache::size() const {
  std::lock_guard lock(mutex_);
  return pipelines_.size();
}

void KernelCache::clear() {
  std::lock_guard lock(mutex_);
  pipelines_.clear();
}

Kernel::Kernel(Context& ctx, KernelDecl decl) : decl_(std::move(decl)), ctx_(&ctx) {
  pipeline_ = &ctx.kernels().get(decl_, &setup_ms_);
}

void Kernel::dispatch(VkCommandBuffer cmd, const Bindings& b, const void* push, uint32_t gx, uint32_t gy,
                      uint32_t gz) const {
  if (!pipeline_) throw Error("dispatch of an empty gpu::Kernel");
  std::vector<Resource> resources;
  resources.reserve(decl_.bindings().size());
  for (const BindingDecl& d : decl_.bindings()) {
    const Resource* r = b.find(d.name);
    if (!r) throw Error(fmt::format("{}: binding '{}' is not bound", decl_.describe(), d.name));
    if (d.slot == Slot::Buffer) {
      if (!r->buffer)
        throw Error(fmt::format("{}: binding '{}' is a storage buffer, but image '{}' is bound there",
                                decl_.describe(), d.name, r->image->name()));
      const Buffer& buf = *r->buffer;
      if (!buf.valid())
        throw Error(fmt::format("{}: binding '{}' is an empty buffer", decl_.describe(), d.name));
      if (buf.size() < d.min_bytes)
        throw Error(fmt::format("{}: binding '{}' is buffer '{}' of {} bytes; the kernel reads {} bytes",
                                decl_.describe(), d.name, buf.name(), buf.size(), d.min_bytes));
      if (d.element_bytes && buf.size() % d.element_bytes != 0)
        throw Error(
            fmt::format("{}: binding '{}' is buffer '{}' of {} bytes, not a whole number of {}-byte "
                        "elements",
                        decl_.describe(), d.name, buf.name(), buf.size(), d.element_bytes));
    } else if (!r->image) {
      throw Error(fmt::format("{}: binding '{}' is a storage image, but buffer '{}' is bound there",
                              decl_.describe(), d.name, r->buffer->name()));
    }
    resources.push_back(*r);
  }
  pipeline_->dispatch(cmd, std::span<const Resource>(resources), push, gx, gy, gz);
}

std::pair<uint32_t, uint32_t> Kernel::groups_2d(uint32_t width, uint32_t height) const {
  const auto& l = pipeline().local_size();
  return {div_up(width, l[0]), div_up(height, l[1])};
}

void Kernel::dispatch_1d(VkCommandBuffer cmd, const Bindings& b, const void* push, uint64_t n) const {
  const uint64_t groups = std::max<uint64_t>(div_up(n, pipeline().local_size()[0]), 1);
  const uint64_t gx = std::min<uint64_t>(groups, ctx_->limits().maxComputeWorkGroupCount[0]);
  dispatch(cmd, b, push, uint32_t(gx), uint32_t((groups + gx - 1) / gx));
}

}  // namespace haze::gpu
