#include "gpu/shader_compiler.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <glslang/Public/ResourceLimits.h>
#include <glslang/Public/ShaderLang.h>
#include <glslang/SPIRV/GlslangToSpv.h>
#include <spirv-tools/libspirv.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <list>

#include "gpu/embedded_sources.hpp"
#include "gpu/error.hpp"
#include "gpu/hash.hpp"

namespace haze::gpu {
namespace {

namespace fs = std::filesystem;

// Bump when the cache file layout or what compile() does with the options changes.
constexpr const char* kCacheFormat = "haze shader cache 1";
constexpr uint32_t kCacheVersion = 1;
constexpr char kCacheMagic[8] = {'H', 'A', 'Z', 'E', 'S', 'P', 'V', '\0'};
constexpr uint32_t kSpirvMagic = 0x07230203;

// What run_glslang() sets, for the cache key: the glslangValidator command line it reproduces.
constexpr const char* kOptions =
    "-V --target-env vulkan1.3 (client vulkan 1.3, input semantics 100, SPIR-V 1.6) -g0 -Os "
    "(strip debug info, optimizer on, size passes) messages spv+vulkan, default version 100, "
    "default resource limits, includes from ShaderSources (includer's folder, then root)";

// <dir>/<key>.spv: this header, then word_count SPIR-V words.
struct CacheHeader {
  char magic[8];
  uint32_t version;
  uint32_t word_count;
  char key[32];
  uint64_t checksum;  // fnv1a64 of the words' bytes
};
static_assert(sizeof(CacheHeader) == 56);

std::string env(const char* name) {
  const char* v = std::getenv(name);
  return v ? std::string(v) : std::string();
}

// "volume/./../common/x.glsl" -> "common/x.glsl"; a path that leaves the root stays as it is (and is
// then not found).
std::string normalize(std::string_view path) {
  std::vector<std::string_view> parts;
  size_t i = 0;
  while (i <= path.size()) {
    size_t j = path.find('/', i);
    if (j == std::string_view::npos) j = path.size();
    std::string_view part = path.substr(i, j - i);
    if (part == "..") {
      if (parts.empty()) return std::string(path);
      parts.pop_back();
    } else if (!part.empty() && part != ".") {
      parts.push_back(part);
    }
    i = j + 1;
  }
  std::string out;
  for (auto part : parts) {
    if (!out.empty()) out += '/';
    out += part;
  }
  return out;
}

std::string folder_of(std::string_view path) {
  size_t slash = path.rfind('/');
  return slash == std::string_view::npos ? std::string() : std::string(path.substr(0, slash));
}

// Where `#include "name"` in `includer` may resolve: the includer's folder first, then the root.
std::vector<std::string> include_candidates(std::string_view includer, std::string_view name, bool local) {
  std::vector<std::string> out;
  if (local) {
    std::string dir = folder_of(includer);
    if (!dir.empty()) out.push_back(normalize(dir + "/" + std::string(name)));
  }
  std::string root = normalize(name);
  if (out.empty() || out.front() != root) out.push_back(root);
  return out;
}

// The header names of every `#include "x"` / `#include <x>` line, whether or not the preprocessor would
// reach it; with the flag true for the "" form.
std::vector<std::pair<std::string, bool>> scan_includes(const std::string& text) {
  std::vector<std::pair<std::string, bool>> out;
  size_t pos = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    if (end == std::string::npos) end = text.size();
    size_t i = pos;
    auto skip_space = [&] {
      while (i < end && (text[i] == ' ' || text[i] == '\t' || text[i] == '\r')) ++i;
    };
    skip_space();
    if (i < end && text[i] == '#') {
      ++i;
      skip_space();
      if (text.compare(i, 7, "include") == 0) {
        i += 7;
        skip_space();
        if (i < end && (text[i] == '"' || text[i] == '<')) {
          char close = text[i] == '"' ? '"' : '>';
          size_t stop = text.find(close, i + 1);
          if (stop != std::string::npos && stop < end)
            out.emplace_back(text.substr(i + 1, stop - i - 1), close == '"');
        }
      }
    }
    pos = end + 1;
  }
  return out;
}

EShLanguage stage_of(std::string_view source) {
  struct Ext {
    const char* ext;
    EShLanguage stage;
  };
  static constexpr Ext kExts[] = {
      {".comp", EShLangCompute},   {".vert", EShLangVertex},      {".frag", EShLangFragment},
      {".geom", EShLangGeometry},  {".tesc", EShLangTessControl}, {".tese", EShLangTessEvaluation},
      {".mesh", EShLangMesh},      {".task", EShLangTask},        {".rgen", EShLangRayGen},
      {".rint", EShLangIntersect}, {".rahit", EShLangAnyHit},     {".rchit", EShLangClosestHit},
      {".rmiss", EShLangMiss},     {".rcall", EShLangCallable},
  };
  for (const auto& e : kExts) {
    std::string_view ext = e.ext;
    if (source.size() > ext.size() && source.substr(source.size() - ext.size()) == ext) return e.stage;
  }
  return EShLangCount;
}

// Serves #include from a ShaderSources tree; names the files by their tree path (so glslang's messages
// say "common/rng.glsl:12"). Remembers the first include it could not find.
class TreeIncluder : public glslang::TShader::Includer {
 public:
  explicit TreeIncluder(const ShaderSources& sources) : sources_(sources) {}

  IncludeResult* includeLocal(const char* header, const char* includer, size_t) override {
    return lookup(header, includer, true);
  }
  IncludeResult* includeSystem(const char* header, const char* includer, size_t) override {
    if (auto* r = lookup(header, includer, false)) return r;
    if (missing_.empty()) missing_ = header;
    // Empty name = failure; glslang puts the text into its error message.
    const std::string& text = messages_.emplace_back(fmt::format("no such shader source '{}'", header));
    return new IncludeResult(std::string(), text.data(), text.size(), nullptr);
  }
  void releaseInclude(IncludeResult* result) override { delete result; }

  const std::string& missing() const { return missing_; }

 private:
  IncludeResult* lookup(const char* header, const char* includer, bool local) {
    for (const auto& path : include_candidates(includer ? includer : "", header, local)) {
      if (const std::string* text = sources_.find(path))
        return new IncludeResult(path, text->data(), text->size(), nullptr);
    }
    return nullptr;
  }

  const ShaderSources& sources_;
  std::string missing_;
  std::list<std::string> messages_;  // stable storage for the failure texts
};

// "ERROR: common/rng.glsl:12: 'x' : undeclared identifier" -> "common/rng.glsl:12: 'x' : undeclared
// identifier" (the first error of the log); "" when there is none.
std::string first_error(const char* log) {
  std::string_view s = log ? log : "";
  size_t pos = 0;
  while (pos < s.size()) {
    size_t end = s.find('\n', pos);
    if (end == std::string_view::npos) end = s.size();
    std::string_view line = s.substr(pos, end - pos);
    if (line.substr(0, 7) == "ERROR: ") {
      line.remove_prefix(7);
      while (!line.empty() && (line.back() == ' ' || line.back() == '\r')) line.remove_suffix(1);
      return std::string(line);
    }
    pos = end + 1;
  }
  return {};
}

// The rest of the log on one line, for errors that are not "ERROR: " lines.
std::string one_line(const char* log) {
  std::string out;
  for (const char* p = log ? log : ""; *p; ++p) {
    char c = *p == '\n' || *p == '\r' ? ' ' : *p;
    if (c == ' ' && (out.empty() || out.back() == ' ')) continue;
    out += c;
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out.empty() ? std::string("unknown error") : out;
}

std::once_flag glslang_once;

}  // namespace

// ---- ShaderSources ----

void ShaderSources::add(std::string path, std::string text) {
  files_[std::move(path)] = std::move(text);
}

const std::string* ShaderSources::find(std::string_view path) const {
  auto it = files_.find(path);
  return it == files_.end() ? nullptr : &it->second;
}

std::vector<std::string> ShaderSources::paths() const {
  std::vector<std::string> out;
  out.reserve(files_.size());
  for (const auto& [path, text] : files_) out.push_back(path);
  return out;
}

const ShaderSources& ShaderSources::embedded() {
  static const ShaderSources tree = [] {
    ShaderSources s;
    for (size_t i = 0; i < embedded::kFileCount; ++i) {
      const embedded::File& f = embedded::kFiles[i];
      std::string text;
      text.reserve(f.size);
      for (size_t k = 0; k < f.piece_count; ++k) text += f.pieces[k];
      if (text.size() != f.size)
        throw Error(fmt::format("embedded shader source '{}' has {} bytes, expected {}", f.path, text.size(),
                                f.size));
      s.add(f.path, std::move(text));
    }
    return s;
  }();
  return tree;
}

// ---- ShaderCompiler ----

ShaderCompiler::ShaderCompiler(std::string cache_dir, const ShaderSources* sources,
                               std::function<void(const std::string&)> warn)
    : dir_(cache_dir.empty() ? default_cache_dir() : std::move(cache_dir)),
      sources_(sources ? sources : &ShaderSources::embedded()),
      warn_(std::move(warn)) {
  if (!warn_)
    warn_ = [](const std::string& text) { std::fprintf(stderr, "haze: warning: %s\n", text.c_str()); };
  cache_on_ = !dir_.empty();
}

std::string ShaderCompiler::default_cache_dir() {
  if (std::string d = env("HAZE_SHADER_CACHE"); !d.empty()) return d;
  if (std::string d = env("XDG_CACHE_HOME"); !d.empty() && d[0] == '/')
    return d + "/haze/shaders";  // XDG: absolute only
  if (std::string d = env("HOME"); !d.empty()) return d + "/.cache/haze/shaders";
  return {};
}

std::string ShaderCompiler::compiler_version() {
  const glslang::Version v = glslang::GetVersion();
  std::string s = fmt::format("glslang {}.{}.{}", v.major, v.minor, v.patch);
  if (v.flavor && *v.flavor) s += fmt::format("-{}", v.flavor);
  return s;
}

std::string ShaderCompiler::label(const ShaderPermutation& p) {
  if (!p.label.empty()) return p.label;
  if (p.defines.empty()) return "default";
  std::string out;
  for (const auto& [name, value] : p.defines) {
    if (!out.empty()) out += '+';
    out += std::string_view(name).substr(0, 5) == "HAZE_" ? name.substr(5) : name;
    if (value != "1") out += "=" + value;
  }
  return out;
}

const std::string& ShaderCompiler::cache_dir() const {
  static const std::string kNone;
  return cache_on_ ? dir_ : kNone;
}

ShaderCacheStats ShaderCompiler::stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

std::string ShaderCompiler::key(const ShaderPermutation& p) const {
  Hasher128 h;
  h.add(kCacheFormat).add(compiler_version()).add(spvSoftwareVersionDetailsString()).add(kOptions);
  h.add(p.source).add_u64(p.defines.size());
  for (const auto& [name, value] : p.defines) h.add(name).add(value);

  // The source and everything it may include, transitively; a candidate path that does not exist counts
  // too (adding it later may shadow the file found now).
  std::map<std::string, const std::string*> files;
  std::deque<std::string> todo{normalize(p.source)};
  files[todo.front()] = sources_->find(todo.front());
  while (!todo.empty()) {
    std::string path = std::move(todo.front());
    todo.pop_front();
    const std::string* text = files[path];
    if (!text) continue;
    for (const auto& [name, local] : scan_includes(*text)) {
      for (auto& candidate : include_candidates(path, name, local)) {
        if (files.count(candidate)) continue;
        files[candidate] = sources_->find(candidate);
        todo.push_back(std::move(candidate));
      }
    }
  }
  h.add_u64(files.size());
  for (const auto& [path, text] : files) {
    h.add(path).add_u64(text != nullptr);
    if (text) h.add(*text);
  }
  return h.digest().hex();
}

std::vector<uint32_t> ShaderCompiler::compile(const ShaderPermutation& p) {
  if (!sources_->find(p.source))
    throw Error(fmt::format("shader {} [{}]: no such shader source '{}'", p.source, label(p), p.source));
  const std::string k = key(p);

  std::vector<uint32_t> words;
  if (cache_on_ && read_cache(k, words)) {
    std::lock_guard lock(mutex_);
    ++stats_.cache_hits;
    return words;
  }

  const auto t0 = std::chrono::steady_clock::now();
  words = run_glslang(p);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  {
    std::lock_guard lock(mutex_);
    ++stats_.compiled;
    stats_.compile_ms += ms;
  }
  if (cache_on_) write_cache(k, words);
  return words;
}

std::vector<uint32_t> ShaderCompiler::run_glslang(const ShaderPermutation& p) const {
  std::call_once(glslang_once, [] { glslang::InitializeProcess(); });
  const std::string where = fmt::format("shader {} [{}]", p.source, label(p));

  const EShLanguage stage = stage_of(p.source);
  if (stage == EShLangCount)
    throw Error(fmt::format("{}: unknown shader stage (want a .comp, .vert, .frag, ... file name)", where));
  const std::string* text = sources_->find(p.source);
  if (!text) throw Error(fmt::format("{}: no such shader source '{}'", where, p.source));

  // What glslangValidator's -DNAME=VALUE writes into its preamble.
  std::string preamble;
  for (const auto& [name, value] : p.defines) {
    if (name.empty() || name.find_first_of(" \t\r\n=") != std::string::npos ||
        value.find_first_of("\r\n") != std::string::npos)
      throw Error(fmt::format("{}: bad define '{}' = '{}'", where, name, value));
    preamble += fmt::format("#define {} {}\n", name, value);
  }

  // Same settings as `glslangValidator -V --target-env vulkan1.3 -g0 -Os` (StandAlone.cpp).
  const EShMessages messages = static_cast<EShMessages>(EShMsgSpvRules | EShMsgVulkanRules);
  glslang::TShader shader(stage);
  const char* strings[] = {text->c_str()};
  const char* names[] = {p.source.c_str()};
  shader.setStringsWithLengthsAndNames(strings, nullptr, names, 1);
  shader.setPreamble(preamble.c_str());
  shader.setEnvInput(glslang::EShSourceGlsl, stage, glslang::EShClientVulkan, 100);
  shader.setEnvClient(glslang::EShClientVulkan, glslang::EShTargetVulkan_1_3);
  shader.setEnvTarget(glslang::EShTargetSpv, glslang::EShTargetSpv_1_6);

  TreeIncluder includer(*sources_);
  if (!shader.parse(GetDefaultResources(), 100, false, messages, includer)) {
    const char* log = shader.getInfoLog();
    if (!includer.missing().empty()) {
      // "a.comp:3: '#include' : no such shader source 'b.glsl' for header name: b.glsl" -> "a.comp:3"
      std::string at = first_error(log);
      at = at.substr(0, at.find(": "));
      throw Error(
          fmt::format("{}: no such shader source '{}' (#include in {})", where, includer.missing(), at));
    }
    std::string first = first_error(log);
    throw Error(fmt::format("{}: {}", where, first.empty() ? one_line(log) : first));
  }

  glslang::TProgram program;  // declared after the shader: destroyed first
  program.addShader(&shader);
  if (!program.link(messages) || !program.mapIO()) {
    const char* log = program.getInfoLog();
    std::string first = first_error(log);
    throw Error(fmt::format("{}: link: {}", where, first.empty() ? one_line(log) : first));
  }

  glslang::SpvOptions options;
  options.stripDebugInfo = true;     // -g0
  options.disableOptimizer = false;  // -Os
  options.optimizeSize = true;
  options.validate = false;
  spv::SpvBuildLogger logger;
  std::vector<uint32_t> words;
  glslang::GlslangToSpv(*program.getIntermediate(stage), words, &logger, &options);
  if (std::string m = logger.getAllMessages(); !m.empty()) {
    std::string line = one_line(m.c_str());
    if (line.find("error") != std::string::npos || words.empty())
      throw Error(fmt::format("{}: SPIR-V generation: {}", where, line));
    warn_(fmt::format("{}: {}", where, line));
  }
  if (words.empty() || words[0] != kSpirvMagic)
    throw Error(fmt::format("{}: SPIR-V generation produced no module", where));
  return words;
}

bool ShaderCompiler::read_cache(const std::string& key, std::vector<uint32_t>& words) const {
  std::ifstream in(fs::path(dir_) / (key + ".spv"), std::ios::binary);
  if (!in) return false;
  CacheHeader h{};
  if (!in.read(reinterpret_cast<char*>(&h), sizeof h)) return false;
  if (std::memcmp(h.magic, kCacheMagic, sizeof h.magic) != 0 || h.version != kCacheVersion ||
      key.size() != sizeof h.key || std::memcmp(h.key, key.data(), sizeof h.key) != 0 || h.word_count == 0 ||
      h.word_count > (256u << 20))
    return false;
  words.resize(h.word_count);
  const auto bytes = static_cast<std::streamsize>(words.size() * sizeof(uint32_t));
  if (!in.read(reinterpret_cast<char*>(words.data()), bytes) ||
      in.peek() != std::ifstream::traits_type::eof() ||
      fnv1a64(kFnv64Basis, words.data(), size_t(bytes)) != h.checksum || words[0] != kSpirvMagic) {
    words.clear();
    return false;
  }
  return true;
}

void ShaderCompiler::write_cache(const std::string& key, const std::vector<uint32_t>& words) {
  std::error_code ec;
  fs::create_directories(dir_, ec);
  if (ec) return cache_off(ec.message());
  if (!fs::is_directory(dir_, ec)) return cache_off(std::strerror(ENOTDIR));

  CacheHeader h{};
  std::memcpy(h.magic, kCacheMagic, sizeof h.magic);
  h.version = kCacheVersion;
  h.word_count = static_cast<uint32_t>(words.size());
  std::memcpy(h.key, key.data(), std::min(key.size(), sizeof h.key));
  h.checksum = fnv1a64(kFnv64Basis, words.data(), words.size() * sizeof(uint32_t));

  // A temp file of this process and call in the same folder, then rename(): readers see the old file or
  // the whole new one.
  static std::atomic<uint64_t> counter{0};
  const std::string path = (fs::path(dir_) / (key + ".spv")).string();
  const std::string tmp = fmt::format("{}.tmp.{}.{}", path, long(::getpid()), counter.fetch_add(1));
  int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return cache_off(std::strerror(errno));
  auto write_all = [fd](const void* data, size_t n) {
    const char* p = static_cast<const char*>(data);
    while (n > 0) {
      ssize_t w = ::write(fd, p, n);
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) return false;
      p += w;
      n -= size_t(w);
    }
    return true;
  };
  bool ok = write_all(&h, sizeof h) && write_all(words.data(), words.size() * sizeof(uint32_t));
  int err = ok ? 0 : (errno ? errno : EIO);
  if (::close(fd) != 0 && ok) {
    ok = false;
    err = errno;
  }
  if (ok && std::rename(tmp.c_str(), path.c_str()) != 0) {
    ok = false;
    err = errno;
  }
  if (!ok) {
    ::unlink(tmp.c_str());
    cache_off(std::strerror(err));
  }
}

void ShaderCompiler::cache_off(const std::string& why) {
  cache_on_ = false;
  {
    std::lock_guard lock(mutex_);
    if (warned_) return;
    warned_ = true;
  }
  warn_(fmt::format("shader cache {}: {}; compiling in memory", dir_, why));
}

}  // namespace haze::gpu
