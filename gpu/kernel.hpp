#pragma once
// Kernels: a compute pass declares its shader, feature defines, bindings and push constants once, in C++
// (KernelDecl). The GLSL binding numbers come from that declaration as generated defines (binding i of
// the declaration is `#define BINDING_<name> i`), the permutation is compiled on demand by the context's
// ShaderCompiler, and the pipeline is created once per context. Resources are bound by name (Bindings):
// a missing, wrong-kind or too-small resource is an error naming the kernel and the binding, before
// anything reaches Vulkan.

#include <vulkan/vulkan.h>

#include <condition_variable>
#include <cstdint>
#include <exception>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include "gpu/pipeline.hpp"
#include "gpu/shader_compiler.hpp"

namespace haze::gpu {

class Buffer;
class Context;
class Image;

// One binding of descriptor set 0, by name. The shader sees BINDING_<name> (the name verbatim: a
// lower-case identifier such as "lights" or "acc_l", so GLSL macros can paste it).
struct BindingDecl {
  std::string name;
  Slot slot = Slot::Buffer;
  uint64_t min_bytes = 0;      // buffers: the shader reads at least this much (0: any buffer, empty included)
  uint64_t element_bytes = 0;  // buffers: the size is a whole number of these (0: any size)
};

class KernelDecl {
 public:
  explicit KernelDecl(std::string source);  // path in the shader tree: "volume/trace.comp"

  // A feature or value define of the permutation ("HAZE_HETERO" = "1").
  KernelDecl& define(const std::string& name, const std::string& value = "1");
  // A storage buffer the shader reads or writes; a second declaration of the same name keeps the larger
  // size expectation (two parts may declare one buffer).
  KernelDecl& buffer(const std::string& name, uint64_t min_bytes = 0, uint64_t element_bytes = 0);
  KernelDecl& image(const std::string& name);
  KernelDecl& push(uint32_t bytes);                      // push constant bytes (multiple of 4)
  KernelDecl& specialize(std::vector<uint32_t> values);  // specialization constants ids 0..n-1

  const std::string& source() const { return source_; }
  const std::vector<std::pair<std::string, std::string>>& defines() const { return defines_; }
  const std::vector<BindingDecl>& bindings() const { return bindings_; }
  uint32_t push_bytes() const { return push_bytes_; }
  const std::vector<uint32_t>& spec() const { return spec_; }
  bool defined(std::string_view name) const;
  bool binds(std::string_view name) const;

  // How messages name the permutation: its feature defines without the HAZE_ prefix ("HETERO+SUN"), or
  // "default", then the specialization constants ("spec 1,0").
  std::string label() const;
  // What the compiler sees: the feature defines, then BINDING_<name> per binding.
  ShaderPermutation permutation() const;
  // Everything that makes two pipelines differ (not the size expectations, which are checked at bind).
  std::string pipeline_key() const;
  // "kernel volume/trace.comp [HETERO+SUN]" for messages.
  std::string describe() const;

 private:
  std::string source_;
  std::vector<std::pair<std::string, std::string>> defines_;
  std::vector<BindingDecl> bindings_;
  uint32_t push_bytes_ = 0;
  std::vector<uint32_t> spec_;
};

// Resources by binding name for one dispatch. Parts add theirs; a kernel takes the ones it declares.
class Bindings {
 public:
  Bindings& set(const std::string& name, const Buffer& b);
  Bindings& set(const std::string& name, const Image& i);
  const Resource* find(const std::string& name) const;

 private:
  std::map<std::string, Resource, std::less<>> resources_;
};

// Throws an Error naming `who` and `what` unless `b` holds `items` records of `stride` floats with `n`
// floats at `offset` in each (a layer read with a stride and offset, as push constants describe it).
void require_strided(const Buffer& b, uint64_t items, uint32_t stride, uint32_t offset, uint32_t n,
                     const std::string& who, const char* what);

// A compiled, created kernel: its declaration and the context's pipeline for it. Cheap to copy.
class Kernel {
 public:
  Kernel() = default;
  // Compiles the permutation (or takes it from the shader cache) and creates the pipeline, unless the
  // context already holds one for the same pipeline_key(). With the context's kernel cache in deferred mode
  // a missing pipeline is compiled in the background instead, and the kernel stays pending (not valid()).
  Kernel(Context& ctx, KernelDecl decl);

  // Binds every declared binding from `b` (checked: present, right kind, large enough, whole elements),
  // pushes `push` (push_bytes() of it) and dispatches gx*gy*gz groups.
  void dispatch(VkCommandBuffer cmd, const Bindings& b, const void* push, uint32_t gx, uint32_t gy = 1,
                uint32_t gz = 1) const;

  bool valid() const { return pipeline_ != nullptr; }
  bool pending() const { return pending_; }  // deferred: still compiling
  const KernelDecl& decl() const { return decl_; }
  const ComputePipeline& pipeline() const;
  // Wall time this construction spent on compiling and creating the pipeline (0 when the context had it).
  double setup_ms() const { return setup_ms_; }
  // Groups covering a width x height image with the kernel's workgroup size.
  std::pair<uint32_t, uint32_t> groups_2d(uint32_t width, uint32_t height) const;
  // Dispatches one invocation per item of [0, n) (and a few more), the groups spread over x and y so that
  // no dimension exceeds the device's limit; the shader indexes with invocation_index()
  // (shaders/common/dispatch.glsl) and returns for indices >= n.
  void dispatch_1d(VkCommandBuffer cmd, const Bindings& b, const void* push, uint64_t n) const;

 private:
  KernelDecl decl_{""};
  Context* ctx_ = nullptr;
  const ComputePipeline* pipeline_ = nullptr;
  bool pending_ = false;
  double setup_ms_ = 0;
};

// The pipelines of a context, by KernelDecl::pipeline_key(); created once, kept for the context's life.
// In deferred mode (a live viewer) a missing pipeline is compiled and created on a worker thread while the
// caller goes on with the pipelines it has: get() returns null at once and pending() counts the work left.
class KernelCache {
 public:
  explicit KernelCache(Context& ctx);
  ~KernelCache();
  // The pipeline for `decl`; `setup_ms` receives the compile and creation time (0 if it existed). Null only
  // in deferred mode, while it compiles. A deferred compile that failed throws its error here, once.
  const ComputePipeline* get(const KernelDecl& decl, double* setup_ms);
  size_t size() const;
  void clear();  // destroys every pipeline (before the device goes); waits for the worker

  void set_deferred(bool on);
  bool deferred() const;
  size_t pending() const;  // deferred compiles not yet finished
  // Labels of the kernels compiling now ("volume/trace.comp [HETERO+GUIDING]"), for a status line.
  std::vector<std::string> compiling() const;
  uint64_t deferred_compiles() const;  // deferred compiles finished so far
  uint64_t misses() const;             // get() calls that returned null (deferred, still compiling)

 private:
  struct Job {
    std::string key;
    KernelDecl decl;
  };
  std::unique_ptr<ComputePipeline> create(const KernelDecl& decl) const;
  void work();

  Context& ctx_;
  mutable std::mutex mutex_;
  std::map<std::string, std::unique_ptr<ComputePipeline>> pipelines_;
  bool deferred_ = false;
  std::vector<Job> queue_;                            // deferred jobs not started
  std::vector<std::string> running_;                  // labels of the jobs in progress
  std::map<std::string, std::exception_ptr> failed_;  // deferred errors, rethrown by get()
  std::map<std::string, double> deferred_ms_;         // compile time of deferred pipelines, by key
  uint64_t deferred_done_ = 0;
  uint64_t misses_ = 0;
  std::unique_ptr<std::thread> worker_;
  std::condition_variable wake_;
  bool stop_ = false;
};

// Device data that kernels read (a medium's grids, the BVH, the lights): it adds its feature defines and
// buffer declarations to a kernel that uses it and binds its buffers by the same names.
class DeviceData {
 public:
  virtual ~DeviceData() = default;
  virtual void declare(KernelDecl& k) const = 0;
  virtual void bind(Bindings& b) const = 0;
};

}  // namespace haze::gpu
