#pragma once
// GLSL compute shaders compiled at run time with glslang's library, one permutation (source + defines)
// at a time, with an on-disk SPIR-V cache. The SPIR-V is word for word what the build's
// `glslangValidator -V --target-env vulkan1.3 -g0 -Os -I<root> <-Ddefines>` writes.

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace haze::gpu {

// GLSL sources by path relative to the shader root: "volume/trace.comp", "common/rng.glsl",
// "nanovdb/PNanoVDB.h".
class ShaderSources {
 public:
  void add(std::string path, std::string text);          // replaces a source of the same path
  const std::string* find(std::string_view path) const;  // nullptr if absent
  std::vector<std::string> paths() const;                // sorted
  static const ShaderSources& embedded();                // the tree compiled into the binary

 private:
  std::map<std::string, std::string, std::less<>> files_;
};

// One permutation of one shader.
struct ShaderPermutation {
  std::string source;  // "volume/trace.comp"
  // In order, as #define NAME VALUE lines: {"HAZE_HETERO","1"}, {"BINDING_SCENE","0"}.
  std::vector<std::pair<std::string, std::string>> defines;
  std::string label;  // how messages name the permutation ("HETERO+SUN"); "" = built from the defines
};

struct ShaderCacheStats {
  uint64_t compiled = 0, cache_hits = 0;
  double compile_ms = 0;  // wall time in glslang (parse, link, SPIR-V generation and optimization)
};

class ShaderCompiler {
 public:
  // cache_dir "" = default_cache_dir(). `sources` must outlive the compiler. `warn` receives one-line
  // warnings (default: prints "haze: warning: <text>" to stderr).
  explicit ShaderCompiler(std::string cache_dir = {},
                          const ShaderSources* sources = nullptr /* = &embedded() */,
                          std::function<void(const std::string&)> warn = {});
  ShaderCompiler(const ShaderCompiler&) = delete;
  ShaderCompiler& operator=(const ShaderCompiler&) = delete;

  // SPIR-V words of the permutation: from the cache, else compiled with glslang and stored. Thread-safe.
  // Throws gpu::Error (one line) for a compile or link error or a missing source; never for the cache.
  std::vector<uint32_t> compile(const ShaderPermutation& p);
  ShaderCacheStats stats() const;
  const std::string& cache_dir() const;  // "" once caching is off for this process (unusable folder)
  // 32 hex digits (FNV-1a 128) over the cache format, compiler_version(), the options, the source path,
  // the defines in order, and the path and text of the source and of every file it may include.
  std::string key(const ShaderPermutation& p) const;
  // $HAZE_SHADER_CACHE, else $XDG_CACHE_HOME/haze/shaders (if absolute), else $HOME/.cache/haze/shaders
  // ("" if none of them is set: no cache).
  static std::string default_cache_dir();
  static std::string compiler_version();  // glslang's version: "glslang 12.0.0"

  // "HETERO+SUN" from {HAZE_HETERO 1}, {HAZE_SUN 1}: names without the HAZE_ prefix, "=value" unless
  // the value is "1"; "default" without defines. p.label when it is set.
  static std::string label(const ShaderPermutation& p);

 private:
  std::vector<uint32_t> run_glslang(const ShaderPermutation& p) const;
  bool read_cache(const std::string& key, std::vector<uint32_t>& words) const;
  void write_cache(const std::string& key, const std::vector<uint32_t>& words);
  void cache_off(const std::string& why);

  std::string dir_;
  const ShaderSources* sources_;
  std::function<void(const std::string&)> warn_;
  std::atomic<bool> cache_on_{false};

  mutable std::mutex mutex_;  // stats_, warned_
  ShaderCacheStats stats_;
  bool warned_ = false;
};

}  // namespace haze::gpu
