#include "gpu/kernel.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>

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

KernelCache::KernelCache(Context& ctx) : ctx_(ctx) {}

KernelCache::~KernelCache() {
  clear();
}

std::unique_ptr<ComputePipeline> KernelCache::create(const KernelDecl& decl) const {
  std::vector<uint32_t> words = ctx_.shaders().compile(decl.permutation());
  std::vector<Slot> slots;
  for (const auto& b : decl.bindings()) slots.push_back(b.slot);
  return std::make_unique<ComputePipeline>(ctx_, fmt::format("{} [{}]", decl.source(), decl.label()), words,
                                           std::move(slots), decl.push_bytes(), decl.spec());
}

const ComputePipeline* KernelCache::get(const KernelDecl& decl, double* setup_ms) {
  if (setup_ms) *setup_ms = 0;
  const std::string key = decl.pipeline_key();
  std::unique_lock lock(mutex_);
  if (auto it = pipelines_.find(key); it != pipelines_.end()) {
    if (auto ms = deferred_ms_.find(key); ms != deferred_ms_.end()) {
      // Its compile time is counted once, by the first kernel that takes it.
      if (setup_ms) *setup_ms = ms->second;
      deferred_ms_.erase(ms);
    }
    return it->second.get();
  }
  if (auto f = failed_.find(key); f != failed_.end()) {
    std::exception_ptr e = f->second;
    failed_.erase(f);
    std::rethrow_exception(e);
  }
  if (deferred_) {
    const std::string label = decl.describe();
    const bool queued = std::any_of(queue_.begin(), queue_.end(), [&](const Job& j) { return j.key == key; });
    if (!queued && std::find(running_.begin(), running_.end(), label) == running_.end()) {
      queue_.push_back({key, decl});
      if (!worker_) worker_ = std::make_unique<std::thread>([this] { work(); });
      wake_.notify_one();
    }
    ++misses_;
    return nullptr;
  }
  // Compiled outside the lock: other threads take existing pipelines meanwhile. Two threads asking for the
  // same new key both compile; the first one stored wins.
  lock.unlock();
  const auto t0 = std::chrono::steady_clock::now();
  std::unique_ptr<ComputePipeline> p = create(decl);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  lock.lock();
  auto& slot = pipelines_[key];
  if (!slot) {
    slot = std::move(p);
    if (setup_ms) *setup_ms = ms;
  }
  return slot.get();
}

namespace {

// A kernel's first dispatch on a helper context of the same device: zero-filled buffers (at least 1 MiB
// each, so that one group's indices stay inside), zero push constants, one group. The shaders read their
// sizes from those zeros and return at once; what matters is that the driver compiled the code.
void warm_up(Context& helper, const KernelDecl& decl) {
  for (const auto& b : decl.bindings())
    if (b.slot != Slot::Buffer) return;  // the kernels that take images are small: not worth it
  Kernel k(helper, decl);
  std::vector<Buffer> buffers;
  buffers.reserve(decl.bindings().size());
  Bindings bind;
  for (const auto& b : decl.bindings()) {
    uint64_t bytes = std::max<uint64_t>(b.min_bytes, 1u << 20);
    if (b.element_bytes) bytes = (bytes + b.element_bytes - 1) / b.element_bytes * b.element_bytes;
    buffers.emplace_back(helper, "warm-up " + b.name, "warm-up", bytes);
    bind.set(b.name, buffers.back());
  }
  std::vector<uint32_t> push(decl.push_bytes() / 4 + 1, 0u);
  helper.submit_and_wait([&](VkCommandBuffer cmd) {
    for (auto& b : buffers) b.fill_zero(cmd);
    compute_barrier(cmd);
    k.dispatch(cmd, bind, push.data(), 1, 1, 1);
  });
}

}  // namespace

void KernelCache::work() {
  // lavapipe compiles a kernel's machine code at its first dispatch, on the queue's own thread: the frame
  // that first used a new kernel would stall for seconds (a minute for the largest trace permutation on a
  // busy machine). So on a CPU device a deferred kernel is also dispatched once on a helper context of the
  // same device, which puts the code into Mesa's shader cache; the helper is destroyed (flushing that
  // cache) before the batch's pipelines are handed over, and the frame's first dispatch finds the code.
  std::unique_ptr<Context> helper;
  std::vector<std::pair<std::string, std::unique_ptr<ComputePipeline>>> batch;
  std::vector<double> batch_ms;
  std::unique_lock lock(mutex_);
  for (;;) {
    wake_.wait(lock, [&] { return stop_ || !queue_.empty() || !batch.empty(); });
    if (stop_) break;
    if (queue_.empty()) {
      // The batch is complete: flush the helper's cache, then publish.
      lock.unlock();
      if (helper) {
        ctx_.take_validation_messages(*helper);
        helper.reset();
      }
      lock.lock();
      for (size_t i = 0; i < batch.size(); ++i) {
        if (!pipelines_.count(batch[i].first)) {
          deferred_ms_[batch[i].first] = batch_ms[i];
          pipelines_[batch[i].first] = std::move(batch[i].second);
        }
        ++deferred_done_;
      }
      batch.clear();
      batch_ms.clear();
      running_.clear();
      continue;
    }
    Job job = std::move(queue_.front());
    queue_.erase(queue_.begin());
    running_.push_back(job.decl.describe());
    lock.unlock();
    const auto t0 = std::chrono::steady_clock::now();
    std::unique_ptr<ComputePipeline> p;
    std::exception_ptr error;
    try {
      p = create(job.decl);
    } catch (...) {
      error = std::current_exception();
    }
    if (p && ctx_.is_cpu()) {
      try {
        if (!helper) helper = std::make_unique<Context>(ctx_.options());
        warm_up(*helper, job.decl);
      } catch (const std::exception& e) {
        // Only the first frame that uses the kernel is slower for it.
        std::fprintf(stderr, "haze: warming up %s failed: %s\n", job.decl.describe().c_str(), e.what());
      }
    }
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    lock.lock();
    if (error) {
      failed_[job.key] = error;
      ++deferred_done_;
      running_.erase(std::find(running_.begin(), running_.end(), job.decl.describe()));
    } else {
      batch.emplace_back(job.key, std::move(p));
      batch_ms.push_back(ms);
    }
  }
  lock.unlock();
  helper.reset();
}

size_t KernelCache::size() const {
  std::lock_guard lock(mutex_);
  return pipelines_.size();
}

void KernelCache::clear() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
    queue_.clear();
  }
  wake_.notify_all();
  if (worker_) {
    worker_->join();
    worker_.reset();
  }
  std::lock_guard lock(mutex_);
  stop_ = false;
  pipelines_.clear();
}

void KernelCache::set_deferred(bool on) {
  std::lock_guard lock(mutex_);
  deferred_ = on;
}

bool KernelCache::deferred() const {
  std::lock_guard lock(mutex_);
  return deferred_;
}

size_t KernelCache::pending() const {
  std::lock_guard lock(mutex_);
  return queue_.size() + running_.size();
}

std::vector<std::string> KernelCache::compiling() const {
  std::lock_guard lock(mutex_);
  std::vector<std::string> out = running_;
  for (const auto& j : queue_) out.push_back(j.decl.describe());
  return out;
}

uint64_t KernelCache::misses() const {
  std::lock_guard lock(mutex_);
  return misses_;
}

uint64_t KernelCache::deferred_compiles() const {
  std::lock_guard lock(mutex_);
  return deferred_done_;
}

Kernel::Kernel(Context& ctx, KernelDecl decl) : decl_(std::move(decl)), ctx_(&ctx) {
  pipeline_ = ctx.kernels().get(decl_, &setup_ms_);
  pending_ = pipeline_ == nullptr;
}

const ComputePipeline& Kernel::pipeline() const {
  if (!pipeline_)
    throw Error(pending_ ? fmt::format("{} is still compiling", decl_.describe())
                         : std::string("use of an empty gpu::Kernel"));
  return *pipeline_;
}

void Kernel::dispatch(VkCommandBuffer cmd, const Bindings& b, const void* push, uint32_t gx, uint32_t gy,
                      uint32_t gz) const {
  if (!pipeline_)
    throw Error(pending_ ? fmt::format("{} is still compiling", decl_.describe())
                         : std::string("dispatch of an empty gpu::Kernel"));
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
