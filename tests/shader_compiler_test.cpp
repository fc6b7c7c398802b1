// The run-time shader compiler on the CPU (no Vulkan device): SPIR-V identical to glslangValidator's, the
// embedded source tree, the on-disk cache (hits, keys, damaged files, unusable folders), errors,
// threads.
#include "gpu/shader_compiler.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <thread>

#include "gpu/error.hpp"
#include "gpu/hash.hpp"
#include "temp_dir.hpp"

#ifndef HAZE_SHADER_DIR
#error "HAZE_SHADER_DIR (the repository's shaders/) must be defined by the build"
#endif
#ifndef HAZE_NANOVDB_INCLUDE_DIR
#error "HAZE_NANOVDB_INCLUDE_DIR (the folder holding nanovdb/PNanoVDB.h) must be defined by the build"
#endif
#ifndef HAZE_GLSLANG_VALIDATOR
#error "HAZE_GLSLANG_VALIDATOR (glslangValidator's path) must be defined by the build"
#endif

namespace haze::gpu {
namespace {

namespace fs = std::filesystem;
using Defines = std::vector<std::pair<std::string, std::string>>;
using Warnings = std::vector<std::string>;

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::vector<uint32_t> read_words(const fs::path& p) {
  std::string bytes = read_text(p);
  std::vector<uint32_t> words(bytes.size() / 4);
  std::memcpy(words.data(), bytes.data(), words.size() * 4);
  return words;
}

// What the build's haze_shader() command writes for `source` with -D<name>=<value> for each define.
std::vector<uint32_t> validator_words(const fs::path& tmp, const std::string& source,
                                      const Defines& defines) {
  std::string cmd = std::string(HAZE_GLSLANG_VALIDATOR) + " -V --target-env vulkan1.3 -g0 -Os -I" +
                    HAZE_SHADER_DIR + " -I" + HAZE_NANOVDB_INCLUDE_DIR;
  for (const auto& [name, value] : defines) cmd += " -D" + name + "=" + value;
  const fs::path out = tmp / "validator.spv", log = tmp / "validator.log";
  cmd += " -o " + out.string() + " " + HAZE_SHADER_DIR + "/" + source + " > " + log.string() + " 2>&1";
  fs::remove(out);
  int rc = std::system(cmd.c_str());
  EXPECT_EQ(rc, 0) << cmd << "\n" << read_text(log);
  return read_words(out);
}

// A small tree: a.comp includes b.glsl (and b.glsl includes c.glsl) and uses VALUE.
ShaderSources small_tree() {
  ShaderSources s;
  s.add("a.comp",
        "#version 460\n"
        "#extension GL_GOOGLE_include_directive : require\n"
        "layout(local_size_x = 1) in;\n"
        "layout(set = 0, binding = 0) buffer Out { uint v[]; } o;\n"
        "#include \"b.glsl\"\n"
        "#ifndef VALUE\n"
        "#define VALUE 1u\n"
        "#endif\n"
        "void main() { o.v[gl_GlobalInvocationID.x] = f(VALUE); }\n");
  s.add("b.glsl",
        "#include \"c.glsl\"\n"
        "uint f(uint x) { return x * K; }\n");
  s.add("c.glsl", "const uint K = 3u;\n");
  return s;
}

// Every binding name the embedded shaders use (BINDING_<name>, and the names given to PIXEL_LAYER*), each
// defined to a distinct number: what a kernel declaration would add (gpu/kernel.hpp), for all of them.
const Defines& all_bindings() {
  static const Defines d = [] {
    std::set<std::string> names;
    const std::regex binding(R"(BINDING_(\w+))"), layer(R"(PIXEL_LAYER(?:_IN|_OUT)?\((\w+)\))");
    const ShaderSources& tree = ShaderSources::embedded();
    for (const auto& path : tree.paths()) {
      const std::string& text = *tree.find(path);
      for (const auto* re : {&binding, &layer})
        for (auto it = std::sregex_iterator(text.begin(), text.end(), *re); it != std::sregex_iterator();
             ++it)
          names.insert((*it)[1]);
    }
    names.erase("name");  // the macro parameter of PIXEL_LAYER itself
    Defines out;
    for (const auto& n : names) out.emplace_back("BINDING_" + n, std::to_string(out.size()));
    return out;
  }();
  return d;
}

// A permutation; sources of the embedded tree also get every binding define.
ShaderPermutation perm(std::string source, Defines defines = {}, std::string label = {}) {
  if (ShaderSources::embedded().find(source))
    defines.insert(defines.end(), all_bindings().begin(), all_bindings().end());
  return ShaderPermutation{std::move(source), std::move(defines), std::move(label)};
}

// Runs f, expects a gpu::Error whose one-line message contains every piece; returns the message.
std::string expect_error(const std::function<void()>& f, std::initializer_list<std::string> pieces) {
  try {
    f();
  } catch (const Error& e) {
    std::string msg = e.what();
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "message is not one line: " << msg;
    for (const auto& p : pieces) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
    return msg;
  }
  ADD_FAILURE() << "no haze::gpu::Error thrown";
  return {};
}

fs::path cache_file(const ShaderCompiler& c, const ShaderPermutation& p) {
  return fs::path(c.cache_dir()) / (c.key(p) + ".spv");
}

const Defines kTraceDefines = {{"HAZE_HETERO", "1"}, {"HAZE_SUN", "1"}, {"HAZE_SURFACES", "1"}};
const Defines kAllTraceFeatures = {{"HAZE_HETERO", "1"},   {"HAZE_HAZE", "1"},     {"HAZE_EMISSION", "1"},
                                   {"HAZE_SUN", "1"},      {"HAZE_LOCAL", "1"},    {"HAZE_MULTI", "1"},
                                   {"HAZE_SURFACES", "1"}, {"HAZE_AREA", "1"},     {"HAZE_TEXTURE", "1"},
                                   {"HAZE_GUIDING", "1"},  {"HAZE_CHROMATIC", "1"}};

// ---- hashes ----

TEST(ShaderCompilerHash, Fnv1aMatchesReference) {
  EXPECT_EQ(fnv1a64(kFnv64Basis, "", 0), kFnv64Basis);
  EXPECT_EQ(fnv1a64(kFnv64Basis, "a", 1), 0xaf63dc4c8601ec8cull);
  EXPECT_EQ(fnv1a64(kFnv64Basis, "foobar", 6), 0x85944171f73967e8ull);

  // 128-bit: against unsigned __int128 arithmetic, and the published FNV-1a 128 of "a".
  const unsigned __int128 prime = (static_cast<unsigned __int128>(1) << 88) + 0x13b;
  std::string text = "The quick brown fox \x01\xff\x80 jumps over the lazy dog";
  for (size_t n = 0; n <= text.size(); ++n) {
    unsigned __int128 ref = (static_cast<unsigned __int128>(kFnv128Basis.hi) << 64) | kFnv128Basis.lo;
    for (size_t i = 0; i < n; ++i) {
      ref ^= static_cast<unsigned char>(text[i]);
      ref *= prime;
    }
    Digest128 d = fnv1a128(kFnv128Basis, text.data(), n);
    EXPECT_EQ(d.hi, uint64_t(ref >> 64)) << n;
    EXPECT_EQ(d.lo, uint64_t(ref)) << n;
  }
  EXPECT_EQ(fnv1a128(kFnv128Basis, "a", 1).hex(), "d228cb696f1a8caf78912b704e4a8964");
  EXPECT_NE(Hasher128().add("ab").add("c").digest(), Hasher128().add("a").add("bc").digest());
}

// ---- the embedded tree ----

TEST(ShaderCompiler, EmbeddedTreeHoldsEveryShaderByteForByte) {
  const ShaderSources& tree = ShaderSources::embedded();
  std::vector<std::string> want;
  for (const auto& e : fs::recursive_directory_iterator(HAZE_SHADER_DIR)) {
    if (!e.is_regular_file()) continue;
    const auto ext = e.path().extension();
    if (ext != ".comp" && ext != ".glsl") continue;
    const std::string key = fs::relative(e.path(), HAZE_SHADER_DIR).generic_string();
    want.push_back(key);
    const std::string* text = tree.find(key);
    ASSERT_NE(text, nullptr) << key;
    EXPECT_EQ(*text, read_text(e.path())) << key;
  }
  want.push_back("nanovdb/PNanoVDB.h");
  std::sort(want.begin(), want.end());
  EXPECT_EQ(tree.paths(), want);
  // CRLF line ends (PNanoVDB.h has them) survive the raw string literals.
  const std::string* pnano = tree.find("nanovdb/PNanoVDB.h");
  ASSERT_NE(pnano, nullptr);
  EXPECT_EQ(*pnano, read_text(fs::path(HAZE_NANOVDB_INCLUDE_DIR) / "nanovdb/PNanoVDB.h"));
  EXPECT_NE(tree.find("volume/trace.comp"), nullptr);
  EXPECT_NE(tree.find("common/rng.glsl"), nullptr);
  EXPECT_EQ(tree.find("volume/nope.comp"), nullptr);
}

// ---- the same SPIR-V as the build's glslangValidator ----

TEST(ShaderCompiler, WordsIdenticalToGlslangValidator) {
  test::TempDir tmp("haze_shc");
  ShaderCompiler compiler((tmp.path() / "cache").string());
  const std::vector<ShaderPermutation> cases = {
      perm("volume/trace.comp", kTraceDefines),
      perm("denoise/accumulate.comp"),
      perm("volume/resolve.comp"),
      perm("surfaces/gbuffer.comp", {{"HAZE_SURFACES", "1"}, {"HAZE_TEXTURE", "1"}}),
  };
  for (const auto& p : cases) {
    SCOPED_TRACE(p.source + " [" + ShaderCompiler::label(p) + "]");
    const auto want = validator_words(tmp.path(), p.source, p.defines);
    ASSERT_GT(want.size(), 5u);
    const auto got = compiler.compile(p);
    EXPECT_EQ(got.size(), want.size());
    EXPECT_TRUE(got == want) << "SPIR-V differs from glslangValidator's";
  }
  EXPECT_EQ(compiler.stats().compiled, cases.size());
}

// ---- the cache ----

TEST(ShaderCompilerCache, SecondCompilerHitsTheCache) {
  test::TempDir tmp("haze_shc");
  const std::string dir = (tmp.path() / "deep/er/cache").string();  // created with parents
  const auto p = perm("volume/resolve.comp");
  std::vector<uint32_t> first;
  {
    ShaderCompiler c(dir);
    first = c.compile(p);
    EXPECT_EQ(c.stats().compiled, 1u);
    EXPECT_EQ(c.stats().cache_hits, 0u);
    EXPECT_GT(c.stats().compile_ms, 0.0);
    EXPECT_TRUE(fs::is_regular_file(cache_file(c, p)));
  }
  ShaderCompiler c(dir);
  const auto second = c.compile(p);
  EXPECT_EQ(c.stats().compiled, 0u);
  EXPECT_EQ(c.stats().cache_hits, 1u);
  EXPECT_EQ(c.stats().compile_ms, 0.0);
  EXPECT_TRUE(second == first);
  // No temp files left behind.
  size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    ++files;
    EXPECT_EQ(e.path().extension(), ".spv") << e.path();
  }
  EXPECT_EQ(files, 1u);
}

TEST(ShaderCompilerCache, KeyChangesWithDefinesAndIncludedFiles) {
  test::TempDir tmp("haze_shc");
  const std::string dir = tmp.path().string();
  const ShaderSources base = small_tree();
  const auto p = perm("a.comp", {{"VALUE", "2u"}});

  auto compile_fresh = [&](const ShaderSources& tree, const ShaderPermutation& q) {
    ShaderCompiler c(dir, &tree);
    auto words = c.compile(q);
    return std::pair{c.key(q), c.stats()};
  };
  const auto first = compile_fresh(base, p);
  const std::string k0 =
      first.first;  // named, not bound: clang 14 lambdas cannot capture structured bindings
  const auto& s0 = first.second;
  EXPECT_EQ(k0.size(), 32u);
  EXPECT_EQ(k0.find_first_not_of("0123456789abcdef"), std::string::npos) << k0;
  EXPECT_EQ(s0.compiled, 1u);
  EXPECT_EQ(compile_fresh(base, p).second.cache_hits, 1u);  // same key, same tree: a hit
  EXPECT_EQ(ShaderCompiler(dir, &base).key(perm("a.comp", {{"VALUE", "2u"}}, "some label")), k0);

  auto expect_new_key = [&](const ShaderSources& tree, const ShaderPermutation& q, const char* what) {
    const auto [k, s] = compile_fresh(tree, q);
    EXPECT_NE(k, k0) << what;
    EXPECT_EQ(s.compiled, 1u) << what;
    EXPECT_EQ(s.cache_hits, 0u) << what;
  };
  expect_new_key(base, perm("a.comp", {{"VALUE", "3u"}}), "changed define value");
  expect_new_key(base, perm("a.comp", {{"VALUE", "2u"}, {"EXTRA", "1"}}), "added define");
  expect_new_key(base, perm("a.comp", {{"EXTRA", "1"}, {"VALUE", "2u"}}), "define order");
  ShaderSources b = small_tree();
  b.add("b.glsl", "#include \"c.glsl\"\nuint f(uint x) { return x * K + 1u; }\n");
  expect_new_key(b, p, "changed included file");
  ShaderSources c = small_tree();
  c.add("c.glsl", "const uint K = 5u;\n");
  expect_new_key(c, p, "changed file included by an included file");
  ShaderSources d = small_tree();
  d.add("unrelated.glsl", "// not included\n");
  EXPECT_EQ(ShaderCompiler(dir, &d).key(p), k0) << "a file that is not included";
}

TEST(ShaderCompilerCache, DamagedFilesAreRecompiledAndRepaired) {
  test::TempDir tmp("haze_shc");
  const std::string dir = tmp.path().string();
  const ShaderSources tree = small_tree();
  const auto p = perm("a.comp");
  std::vector<uint32_t> good;
  fs::path file;
  {
    ShaderCompiler c(dir, &tree);
    good = c.compile(p);
    file = cache_file(c, p);
  }
  const std::string intact = read_text(file);
  ASSERT_GT(intact.size(), 64u);

  auto damage_and_check = [&](const std::string& bytes, const char* what) {
    std::ofstream(file, std::ios::binary | std::ios::trunc) << bytes;
    {
      ShaderCompiler c(dir, &tree);
      EXPECT_TRUE(c.compile(p) == good) << what;
      EXPECT_EQ(c.stats().compiled, 1u) << what;
      EXPECT_EQ(c.stats().cache_hits, 0u) << what;
    }
    EXPECT_EQ(read_text(file), intact) << what << ": file not repaired";
    ShaderCompiler c(dir, &tree);
    EXPECT_TRUE(c.compile(p) == good) << what;
    EXPECT_EQ(c.stats().cache_hits, 1u) << what;
  };
  std::string flipped = intact;
  flipped[flipped.size() - 7] ^= 0x10;
  damage_and_check(flipped, "a flipped bit in the words");
  damage_and_check(intact.substr(0, intact.size() / 2), "truncated");
  damage_and_check(intact.substr(0, 20), "truncated header");
  damage_and_check(intact + "xyz!", "trailing bytes");
  damage_and_check("", "empty file");
  std::string wrong_magic = intact;
  wrong_magic[0] = 'X';
  damage_and_check(wrong_magic, "wrong magic");
  // Another permutation's (valid) file under this key: the key in the header differs.
  {
    ShaderCompiler c(dir, &tree);
    const auto other = perm("a.comp", {{"VALUE", "9u"}});
    c.compile(other);
    damage_and_check(read_text(cache_file(c, other)), "another key's file");
  }
}

// A folder that cannot hold the cache: one warning, then compiles in memory, stats right.
void check_unusable_cache(const std::string& dir, const std::string& why) {
  SCOPED_TRACE(why + ": " + dir);
  Warnings warnings;
  const ShaderSources tree = small_tree();
  ShaderCompiler c(dir, &tree, [&](const std::string& w) { warnings.push_back(w); });
  EXPECT_EQ(c.cache_dir(), dir);
  const auto w1 = c.compile(perm("a.comp"));
  const auto w2 = c.compile(perm("a.comp", {{"VALUE", "4u"}}));
  const auto w3 = c.compile(perm("a.comp"));
  EXPECT_TRUE(w1 == w3);
  EXPECT_FALSE(w1 == w2);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_EQ(warnings[0].find('\n'), std::string::npos);
  EXPECT_EQ(warnings[0].rfind("shader cache " + dir + ": ", 0), 0u) << warnings[0];
  EXPECT_NE(warnings[0].find("; compiling in memory"), std::string::npos) << warnings[0];
  EXPECT_EQ(c.cache_dir(), "");
  EXPECT_EQ(c.stats().compiled, 3u);
  EXPECT_EQ(c.stats().cache_hits, 0u);
}

TEST(ShaderCompilerCache, UnusableFolderWarnsOnceAndCompilesInMemory) {
  test::TempDir tmp("haze_shc");
  // A path whose parent is a regular file: fails for root too.
  std::ofstream(tmp.path() / "file") << "not a folder";
  check_unusable_cache((tmp.path() / "file/cache").string(), "parent is a file");
  check_unusable_cache((tmp.path() / "file").string(), "path is a file");

  // A read-only folder (chmod 0555); root writes anyway, so there the check above stands in for it.
  const fs::path ro = tmp.path() / "ro";
  fs::create_directories(ro);
  ASSERT_EQ(::chmod(ro.c_str(), 0555), 0);
  const bool can_write = ::access(ro.c_str(), W_OK) == 0;  // root
  if (!can_write) {
    check_unusable_cache(ro.string(), "read-only folder");
    check_unusable_cache((ro / "sub").string(), "under a read-only folder");
  }
  ::chmod(ro.c_str(), 0755);
  if (can_write)
    std::printf("note: running as root, chmod 0555 does not stop writes: checked the file-parent case\n");
}

// ---- errors ----

TEST(ShaderCompiler, CompileErrorIsOneLineNamingTheIncludedFile) {
  test::TempDir tmp("haze_shc");
  ShaderSources tree = small_tree();
  tree.add("b.glsl",
           "#include \"c.glsl\"\n"
           "// line 2\n"
           "uint f(uint x) { return x * undeclared_thing; }\n");
  ShaderCompiler c(tmp.path().string(), &tree);
  std::string msg = expect_error(
      [&] {
        c.compile(perm("a.comp", {{"VALUE", "2u"}}, "MY+LABEL"));
      },
      {"shader a.comp [MY+LABEL]: ", "b.glsl:3: ", "undeclared_thing"});
  EXPECT_EQ(msg.rfind("shader a.comp [MY+LABEL]: b.glsl:3: ", 0), 0u) << msg;
  // The default label comes from the defines.
  expect_error(
      [&] {
        c.compile(perm("a.comp", {{"HAZE_HETERO", "1"}, {"VALUE", "2u"}}));
      },
      {"shader a.comp [HETERO+VALUE=2u]: b.glsl:3: "});
  // An error in the top-level file names it with its line.
  ShaderSources top = small_tree();
  top.add("a.comp", "#version 460\nlayout(local_size_x = 1) in;\nvoid main() { int x = ; }\n");
  ShaderCompiler c2(tmp.path().string(), &top);
  expect_error([&] { c2.compile(perm("a.comp")); }, {"shader a.comp [default]: a.comp:3: "});
  EXPECT_EQ(c.stats().compiled, 0u);
}

TEST(ShaderCompiler, LinkErrorIsOneLine) {
  test::TempDir tmp("haze_shc");
  ShaderSources tree;
  tree.add("nomain.comp", "#version 460\nlayout(local_size_x = 1) in;\nvoid not_main() {}\n");
  ShaderCompiler c(tmp.path().string(), &tree);
  expect_error([&] { c.compile(perm("nomain.comp")); }, {"shader nomain.comp [default]: link: ", "main"});
}

TEST(ShaderCompiler, MissingSourceOrIncludeIsAClearError) {
  test::TempDir tmp("haze_shc");
  ShaderSources tree = small_tree();
  tree.add("b.glsl", "// first line\n#include \"nope.glsl\"\nuint f(uint x) { return x; }\n");
  ShaderCompiler c(tmp.path().string(), &tree);
  expect_error([&] { c.compile(perm("a.comp", {}, "L")); },
               {"shader a.comp [L]: no such shader source 'nope.glsl'", "b.glsl:2"});
  expect_error([&] { c.compile(perm("gone.comp", {}, "L")); },
               {"shader gone.comp [L]: no such shader source 'gone.comp'"});
  EXPECT_EQ(c.stats().compiled, 0u);
  EXPECT_TRUE(fs::is_empty(tmp.path()));
}

TEST(ShaderCompiler, IncludesResolveInTheIncludersFolderFirst) {
  test::TempDir tmp("haze_shc");
  ShaderSources tree;
  tree.add("x/a.comp",
           "#version 460\n#extension GL_GOOGLE_include_directive : require\nlayout(local_size_x = 1) in;\n"
           "layout(set = 0, binding = 0) buffer Out { uint v[]; } o;\n"
           "#include \"b.glsl\"\n#include \"common/k.glsl\"\nvoid main() { o.v[0] = B + K; }\n");
  tree.add("x/b.glsl", "const uint B = 1u;\n");
  tree.add("b.glsl", "this does not compile\n");  // shadowed by x/b.glsl
  // Found at the root (x/common/k.glsl does not exist); includes a path relative to its own folder.
  tree.add("common/k.glsl", "#include \"../x/b2.glsl\"\nconst uint K = B2;\n");
  tree.add("x/b2.glsl", "const uint B2 = 2u;\n");
  ShaderCompiler c(tmp.path().string(), &tree);
  EXPECT_NO_THROW(c.compile(perm("x/a.comp")));
  // Shadowing the root's common/k.glsl by x/common/k.glsl changes the key.
  ShaderSources shadowed = tree;
  shadowed.add("x/common/k.glsl", "const uint K = 7u;\n");
  EXPECT_NE(ShaderCompiler(tmp.path().string(), &shadowed).key(perm("x/a.comp")), c.key(perm("x/a.comp")));
}

// ---- environment, threads ----

class EnvGuard {
 public:
  explicit EnvGuard(std::initializer_list<const char*> names) {
    for (const char* n : names) {
      const char* v = std::getenv(n);
      saved_.emplace_back(n, v ? std::optional<std::string>(v) : std::nullopt);
    }
  }
  ~EnvGuard() {
    for (const auto& [n, v] : saved_) v ? ::setenv(n.c_str(), v->c_str(), 1) : ::unsetenv(n.c_str());
  }

 private:
  std::vector<std::pair<std::string, std::optional<std::string>>> saved_;
};

TEST(ShaderCompiler, DefaultCacheDirFollowsTheEnvironment) {
  EnvGuard guard({"HAZE_SHADER_CACHE", "XDG_CACHE_HOME", "HOME"});
  ::setenv("HAZE_SHADER_CACHE", "/tmp/haze-a", 1);
  ::setenv("XDG_CACHE_HOME", "/tmp/xdg", 1);
  ::setenv("HOME", "/tmp/home", 1);
  EXPECT_EQ(ShaderCompiler::default_cache_dir(), "/tmp/haze-a");
  EXPECT_EQ(ShaderCompiler().cache_dir(), "/tmp/haze-a");  // "" = the default
  ::unsetenv("HAZE_SHADER_CACHE");
  EXPECT_EQ(ShaderCompiler::default_cache_dir(), "/tmp/xdg/haze/shaders");
  ::setenv("XDG_CACHE_HOME", "", 1);
  EXPECT_EQ(ShaderCompiler::default_cache_dir(), "/tmp/home/.cache/haze/shaders");
  ::setenv("XDG_CACHE_HOME", "relative/cache", 1);  // the XDG spec: ignore a relative path
  EXPECT_EQ(ShaderCompiler::default_cache_dir(), "/tmp/home/.cache/haze/shaders");
  ::unsetenv("XDG_CACHE_HOME");
  EXPECT_EQ(ShaderCompiler::default_cache_dir(), "/tmp/home/.cache/haze/shaders");
  ::unsetenv("HOME");
  EXPECT_EQ(ShaderCompiler::default_cache_dir(), "");
}

TEST(ShaderCompiler, ConcurrentCompilesOfDifferentPermutations) {
  test::TempDir tmp("haze_shc");
  const std::vector<ShaderPermutation> perms = {perm("volume/resolve.comp"), perm("denoise/tonemap.comp"),
                                                perm("denoise/taa.comp"), perm("surfaces/trace_rays.comp")};
  std::vector<std::vector<uint32_t>> want;
  {
    ShaderCompiler serial((tmp.path() / "serial").string());
    for (const auto& p : perms) want.push_back(serial.compile(p));
  }
  ShaderCompiler shared((tmp.path() / "shared").string());
  std::vector<std::vector<uint32_t>> got(perms.size());
  std::vector<std::string> errors(2);
  std::vector<std::thread> threads;
  for (size_t t = 0; t < 2; ++t)
    threads.emplace_back([&, t] {
      try {
        for (size_t i = t; i < perms.size(); i += 2) got[i] = shared.compile(perms[i]);
      } catch (const std::exception& e) {
        errors[t] = e.what();
      }
    });
  for (auto& th : threads) th.join();
  for (size_t t = 0; t < 2; ++t) EXPECT_EQ(errors[t], "") << "thread " << t;
  for (size_t i = 0; i < perms.size(); ++i) EXPECT_TRUE(got[i] == want[i]) << perms[i].source;
  EXPECT_EQ(shared.stats().compiled, perms.size());
  EXPECT_EQ(shared.stats().cache_hits, 0u);
}

TEST(ShaderCompiler, VersionAndLabels) {
  EXPECT_EQ(ShaderCompiler::compiler_version().rfind("glslang ", 0), 0u)
      << ShaderCompiler::compiler_version();
  EXPECT_EQ(ShaderCompiler::label(perm("x.comp")), "default");
  EXPECT_EQ(ShaderCompiler::label(perm("x.comp", {{"HAZE_HETERO", "1"}, {"BINDING_SCENE", "0"}})),
            "HETERO+BINDING_SCENE=0");
  EXPECT_EQ(ShaderCompiler::label(perm("x.comp", {{"HAZE_HETERO", "1"}}, "mine")), "mine");
}

// Cold compile of the largest permutation against a cache hit (printed, not asserted).
TEST(ShaderCompiler, TimesFullTraceCompileAgainstCacheHit) {
  test::TempDir tmp("haze_shc");
  const auto p = perm("volume/trace.comp", kAllTraceFeatures);
  using clock = std::chrono::steady_clock;
  auto ms = [](clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); };
  std::vector<uint32_t> cold;
  double cold_ms = 0, glslang_ms = 0;
  {
    ShaderCompiler c(tmp.path().string());
    auto t0 = clock::now();
    cold = c.compile(p);
    cold_ms = ms(clock::now() - t0);
    glslang_ms = c.stats().compile_ms;
  }
  ShaderCompiler c(tmp.path().string());
  auto t0 = clock::now();
  auto hit = c.compile(p);
  double hit_ms = ms(clock::now() - t0);
  EXPECT_EQ(c.stats().cache_hits, 1u);
  EXPECT_TRUE(hit == cold);
  std::printf(
      "volume/trace.comp [%s]: %zu words; cold compile %.1f ms (glslang %.1f ms), cache hit %.2f ms\n",
      ShaderCompiler::label(p).c_str(), cold.size(), cold_ms, glslang_ms, hit_ms);
  const auto want = validator_words(tmp.path(), p.source, p.defines);
  EXPECT_TRUE(cold == want) << "SPIR-V differs from glslangValidator's";
}

}  // namespace
}  // namespace haze::gpu
