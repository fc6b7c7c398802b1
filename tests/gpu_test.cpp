// The GPU layer on whatever device the environment pins (lavapipe under ctest), validation on.
#include "gpu/gpu.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <glm/glm.hpp>
#include <limits>
#include <memory>
#include <random>

namespace haze::gpu {
namespace {

#ifndef GPU_TEST_SPV
#error "GPU_TEST_SPV (path of gpu_test_add.spv) must be defined by the build"
#endif
#ifndef GPU_TEST_IMAGE_SPV
#error "GPU_TEST_IMAGE_SPV (path of gpu_test_image.spv) must be defined by the build"
#endif

struct AddPush {
  uint32_t n;
  float k;
};

struct ImagePush {
  uint32_t width, height;
  float bias;
};

// One Context and one pipeline per process: creating them is the slow part on lavapipe.
struct Shared {
  std::unique_ptr<Context> ctx;
  std::unique_ptr<ComputePipeline> add;
};
Shared& shared() {
  static Shared s;
  return s;
}

std::filesystem::path temp_root() {
  return std::filesystem::temp_directory_path() / ("haze_gpu_test_" + std::to_string(::getpid()));
}
std::filesystem::path temp_dir() {
  std::filesystem::create_directories(temp_root());
  return temp_root();
}

class GpuEnvironment : public ::testing::Environment {
 public:
  void TearDown() override {  // before main returns, while the Vulkan loader is surely alive
    shared().add.reset();
    shared().ctx.reset();
    std::error_code ec;
    std::filesystem::remove_all(temp_root(), ec);
  }
};
[[maybe_unused]] auto* const gpu_environment = ::testing::AddGlobalTestEnvironment(new GpuEnvironment);

std::string joined(const std::vector<std::string>& log) {
  std::string s;
  for (const auto& l : log) s += l + "\n";
  return s;
}

class Gpu : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (!shared().ctx) {
      ContextOptions o;
      o.validation = true;
      shared().ctx = std::make_unique<Context>(o);
      shared().add = std::make_unique<ComputePipeline>(*shared().ctx, GPU_TEST_SPV, 3, sizeof(AddPush));
    }
  }
  void TearDown() override { EXPECT_EQ(ctx().validation_messages(), 0u) << joined(ctx().validation_log()); }
  static Context& ctx() { return *shared().ctx; }
  static const ComputePipeline& add() { return *shared().add; }

  static std::vector<float> random_floats(size_t n, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> d(-1000, 1000);
    std::vector<float> v(n);
    for (auto& x : v) x = static_cast<float>(d(rng)) / 8.0f;  // exact in float: sums are exact too
    return v;
  }

  // Finite, normal IEEE halves as raw bits: copies must keep them bit for bit.
  static std::vector<uint16_t> random_halves(size_t n, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<uint32_t> sign(0, 1), exponent(1, 30), mantissa(0, 1023);
    std::vector<uint16_t> v(n);
    for (auto& h : v) h = static_cast<uint16_t>(sign(rng) << 15 | exponent(rng) << 10 | mantissa(rng));
    return v;
  }

  static std::string error_of(const std::function<void()>& f) {
    try {
      f();
    } catch (const Error& e) {
      return e.what();
    }
    return "(no error)";
  }
};

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

TEST_F(Gpu, BufferRoundtrip) {
  auto data = random_floats(1000, 1);
  Buffer b(ctx(), "roundtrip", "test", data.size() * sizeof(float), "f32");
  EXPECT_TRUE(b.valid());
  EXPECT_EQ(b.size(), 4000u);
  b.upload(data);
  EXPECT_EQ(b.download_vector<float>(), data);

  // Partial ranges at an offset.
  std::vector<float> part = {1.5f, 2.5f, 3.5f};
  b.upload(part.data(), part.size() * sizeof(float), 10 * sizeof(float));
  std::vector<float> back(3);
  b.download(back.data(), back.size() * sizeof(float), 10 * sizeof(float));
  EXPECT_EQ(back, part);

  b.fill_zero();
  for (float x : b.download_vector<float>()) ASSERT_EQ(x, 0.0f);

  EXPECT_THROW(b.upload(data.data(), 8, 3996), Error);
  try {
    b.download(back.data(), 8, 3996);
    FAIL() << "out-of-range download did not throw";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'roundtrip'"), std::string::npos) << e.what();
  }
}

TEST_F(Gpu, BufferMoveKeepsOneLedgerEntry) {
  uint64_t before = ctx().ledger().total();
  size_t entries_before = ctx().ledger().entries().size();
  {
    Buffer a(ctx(), "moved", "test", 1000, "u8");
    EXPECT_EQ(ctx().ledger().entries().size(), entries_before + 1);
    auto e = ctx().ledger().entries().back();
    EXPECT_EQ(e.name, "moved");
    EXPECT_EQ(e.category, "test");
    EXPECT_EQ(e.format, "u8");
    EXPECT_EQ(e.requested, 1000u);
    EXPECT_EQ(e.bytes, a.allocated());
    EXPECT_GE(e.bytes, 1000u);
    EXPECT_EQ(ctx().ledger().total(), before + a.allocated());

    Buffer b(std::move(a));
    EXPECT_FALSE(a.valid());  // NOLINT(bugprone-use-after-move): moved-from state is part of the contract
    Buffer c;
    c = std::move(b);
    EXPECT_TRUE(c.valid());
    EXPECT_EQ(c.name(), "moved");
    EXPECT_EQ(ctx().ledger().entries().size(), entries_before + 1);
  }
  EXPECT_EQ(ctx().ledger().total(), before);
  EXPECT_EQ(ctx().ledger().entries().size(), entries_before);
}

TEST_F(Gpu, ComputeAddMatchesCpu) {
  const uint32_t n = 1000;  // not a multiple of the workgroup size
  auto a = random_floats(n, 2), b = random_floats(n, 3);
  Buffer ba(ctx(), "a", "test", n * 4, "f32"), bb(ctx(), "b", "test", n * 4, "f32"),
      bc(ctx(), "c", "test", n * 4, "f32");
  ba.upload(a);
  bb.upload(b);
  EXPECT_EQ(add().local_size(), (std::array<uint32_t, 3>{64, 1, 1}));
  AddPush push{n, 0.25f};
  ctx().submit_and_wait([&](VkCommandBuffer cmd) {
    add().dispatch(cmd, {&ba, &bb, &bc}, &push, div_up(n, add().local_size()[0]));
  });
  auto c = bc.download_vector<float>();
  ASSERT_EQ(c.size(), n);
  for (uint32_t i = 0; i < n; ++i) ASSERT_EQ(c[i], a[i] + b[i] + push.k) << "i=" << i;
  EXPECT_GT(add().creation_ms(), 0.0);
  EXPECT_EQ(add().path(), GPU_TEST_SPV);

  // Specialization constant 0 (EXTRA) and a second dispatch reading the first one's output.
  ComputePipeline extra(ctx(), GPU_TEST_SPV, 3, sizeof(AddPush), {5});
  Buffer bd(ctx(), "d", "test", n * 4, "f32");
  ctx().submit_and_wait([&](VkCommandBuffer cmd) {
    extra.dispatch(cmd, {&ba, &bb, &bc}, &push, div_up(n, 64));
    compute_barrier(cmd);
    add().dispatch(cmd, {&bc, &bb, &bd}, &push, div_up(n, 64));
  });
  auto d = bd.download_vector<float>();
  for (uint32_t i = 0; i < n; ++i) {
    float ci = a[i] + b[i] + push.k + 5.0f;
    ASSERT_EQ(d[i], ci + b[i] + push.k) << "i=" << i;
  }
}

// A CPU driver's shader threads flush denormal floats (FTZ and DAZ, set while the Context creates the
// device): without that an operation on a denormal costs a microcode assist, 20 times slower on lavapipe. The
// test thread's own floating-point mode is left as it was. A GPU flushes or keeps denormals as its hardware
// does, and the Context sets the flush modes on x86 only: there either result is exact.
TEST_F(Gpu, CpuDeviceShadersFlushDenormals) {
#if defined(__SSE__) || defined(__x86_64__)
  const bool context_flushes = true;
#else
  const bool context_flushes = false;
#endif
  const float tiny = std::numeric_limits<float>::min();  // smallest normal float
  volatile float half_tiny = tiny;
  half_tiny = half_tiny * 0.5f;
  EXPECT_NE(half_tiny, 0.0f) << "the calling thread's denormals must survive the Context";
  // c = a + b + k: a denormal sum (FTZ) and a denormal input (DAZ), each next to a normal control.
  std::vector<float> a = {1.5f * tiny, half_tiny, 3.0f * tiny, 1.0f};
  std::vector<float> b = {-tiny, 0.0f, -tiny, half_tiny};
  const uint32_t n = static_cast<uint32_t>(a.size());
  Buffer ba(ctx(), "a", "test", n * 4, "f32"), bb(ctx(), "b", "test", n * 4, "f32"),
      bc(ctx(), "c", "test", n * 4, "f32");
  ba.upload(a);
  bb.upload(b);
  AddPush push{n, 0.0f};
  ctx().submit_and_wait([&](VkCommandBuffer cmd) { add().dispatch(cmd, {&ba, &bb, &bc}, &push, 1); });
  auto c = bc.download_vector<float>();
  if (ctx().is_cpu() && context_flushes) {
    EXPECT_EQ(c[0], 0.0f) << "a denormal result was kept";
    EXPECT_EQ(c[1], 0.0f) << "a denormal input was kept";
  } else {
    EXPECT_TRUE(c[0] == 0.0f || c[0] == 0.5f * tiny) << c[0];
    EXPECT_TRUE(c[1] == 0.0f || c[1] == half_tiny) << c[1];
  }
  EXPECT_EQ(c[2], 2.0f * tiny);
  EXPECT_EQ(c[3], 1.0f);
}

TEST_F(Gpu, DispatchChecksItsArguments) {
  Buffer x(ctx(), "x", "test", 64), y(ctx(), "y", "test", 64);
  AddPush push{16, 0};
  EXPECT_THROW(ctx().submit_and_wait([&](VkCommandBuffer cmd) {
    add().dispatch(cmd, {&x, &y}, &push, 1);
  }),
               Error);
  EXPECT_THROW(ctx().submit_and_wait([&](VkCommandBuffer cmd) {
    add().dispatch(cmd, {&x, &y, &x}, nullptr, 1);
  }),
               Error);
  // The command buffer left half-recorded by the throws is usable again.
  std::vector<const Buffer*> list = {&x, &y, &x};
  ctx().submit_and_wait([&](VkCommandBuffer cmd) { add().dispatch(cmd, list, &push, 1); });
  // Past maxStorageBufferRange a buffer cannot be bound whole (its pages are never touched here).
  if (ctx().features().buffer_device_address) {
    Buffer big(ctx(), "big grid", "test", uint64_t{ctx().limits().maxStorageBufferRange} + 4);
    try {
      ctx().submit_and_wait([&](VkCommandBuffer cmd) { add().dispatch(cmd, {&big, &y, &x}, &push, 1); });
      ADD_FAILURE() << "oversized binding accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("'big grid'"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("maxStorageBufferRange"), std::string::npos) << e.what();
    }
  }
  // Bindings beyond num_buffers are caught from the SPIR-V.
  EXPECT_THROW(ComputePipeline(ctx(), GPU_TEST_SPV, 2, sizeof(AddPush)), Error);
  EXPECT_THROW(ComputePipeline(ctx(), GPU_TEST_SPV, 3, 6), Error);
}

TEST_F(Gpu, TimestampsAreOrdered) {
  const uint32_t n = 1 << 18;
  Buffer a(ctx(), "ta", "test", n * 4), b(ctx(), "tb", "test", n * 4), c(ctx(), "tc", "test", n * 4);
  a.fill_zero();
  b.fill_zero();
  Timer timer(ctx(), 8);
  AddPush push{n, 1.0f};
  for (int frame = 0; frame < 2; ++frame) {  // the pool is reused across frames
    ctx().submit_and_wait([&](VkCommandBuffer cmd) {
      timer.reset(cmd);
      timer.begin(cmd, "first");
      add().dispatch(cmd, {&a, &b, &c}, &push, div_up(n, 64));
      timer.end(cmd);
      compute_barrier(cmd);
      timer.begin(cmd, "second");
      add().dispatch(cmd, {&c, &b, &a}, &push, div_up(n, 64));
      timer.end(cmd);
    });
    auto scopes = timer.read_scopes();
    ASSERT_EQ(scopes.size(), 2u);
    EXPECT_EQ(scopes[0].pass, "first");
    EXPECT_EQ(scopes[1].pass, "second");
    EXPECT_EQ(scopes[0].begin_ms, 0.0);
    EXPECT_LE(scopes[0].begin_ms, scopes[0].end_ms);
    EXPECT_LE(scopes[0].end_ms, scopes[1].begin_ms);
    EXPECT_LE(scopes[1].begin_ms, scopes[1].end_ms);
    auto ms = timer.read_ms();
    ASSERT_EQ(ms.size(), 2u);
    for (const auto& [pass, t] : ms) {
      EXPECT_GE(t, 0.0) << pass;
      EXPECT_LT(t, 60000.0) << pass;
    }
    if (timer.supported()) {
      EXPECT_GT(ms[0].second + ms[1].second, 0.0);
    }
  }
  EXPECT_EQ(a.download_vector<float>()[7], 4.0f);  // frame 1 leaves a = 2, frame 2: (2 + 0 + 1) + 0 + 1
  EXPECT_GT(ctx().timestamp_period_ns(), 0.0f);
  EXPECT_THROW(ctx().submit_and_wait([&](VkCommandBuffer cmd) { timer.end(cmd); }), Error);
}

TEST_F(Gpu, LedgerAddRemovePerCategoryPeakJson) {
  MemoryLedger l;
  uint64_t a = l.add({"density", "scene data", "f32", 1000, 999});
  uint64_t b = l.add({"radiance", "per-frame temporaries", "rgba32f", 4096});
  uint64_t c = l.add({"majorant", "scene data", "f32", 256, 256});
  EXPECT_NE(a, b);
  EXPECT_NE(b, c);
  EXPECT_EQ(l.total(), 5352u);
  EXPECT_EQ(l.peak(), 5352u);
  EXPECT_EQ(l.per_category(),
            (std::map<std::string, uint64_t>{{"scene data", 1256}, {"per-frame temporaries", 4096}}));
  l.remove(b);
  l.remove(b);  // twice: ignored
  EXPECT_EQ(l.total(), 1256u);
  EXPECT_EQ(l.peak(), 5352u);
  l.add({"history", "previous-frame data", "rgba16f", 100, 96});
  EXPECT_EQ(l.total(), 1356u);
  EXPECT_EQ(l.total_requested(), 999u + 256u + 96u);
  auto e = l.entries();
  ASSERT_EQ(e.size(), 3u);
  EXPECT_EQ(e[0].name, "density");
  EXPECT_EQ(e[1].name, "majorant");
  EXPECT_EQ(e[2].name, "history");
  nlohmann::json expected = {{"entries",
                              {{{"name", "density"},
                                {"category", "scene data"},
                                {"format", "f32"},
                                {"bytes", 1000},
                                {"requested", 999}},
                               {{"name", "majorant"},
                                {"category", "scene data"},
                                {"format", "f32"},
                                {"bytes", 256},
                                {"requested", 256}},
                               {{"name", "history"},
                                {"category", "previous-frame data"},
                                {"format", "rgba16f"},
                                {"bytes", 100},
                                {"requested", 96}}}},
                             {"per_category", {{"scene data", 1256}, {"previous-frame data", 100}}},
                             {"total", 1356},
                             {"peak", 5352}};
  EXPECT_EQ(l.to_json(), expected) << l.to_json().dump(2);
}

TEST_F(Gpu, ContextDescribesItsDevice) {
  auto d = ctx().describe();
  for (const char* key : {"name", "type", "driver", "api_version", "index"})
    EXPECT_TRUE(d.contains(key)) << key;
  EXPECT_EQ(d["name"], ctx().device_name());
  EXPECT_FALSE(ctx().driver_info().empty());
  EXPECT_TRUE(ctx().validation_enabled());
  if (ctx().driver_info().find("llvmpipe") != std::string::npos) {
    EXPECT_TRUE(ctx().is_cpu());
    EXPECT_NE(ctx().driver_info().find("Mesa"), std::string::npos);
  }
  auto list = list_devices();
  ASSERT_FALSE(list.empty());
  ASSERT_LT(ctx().device_index(), list.size());
  EXPECT_EQ(list[ctx().device_index()]["name"], ctx().device_name());
  EXPECT_EQ(list[ctx().device_index()]["suitable"], true);
}

TEST_F(Gpu, DeviceSelectionByIndexAndBadName) {
  {
    ContextOptions o;
    o.device = "0";
    o.validation = true;
    Context c0(o);
    EXPECT_EQ(c0.device_index(), 0u);
    EXPECT_EQ(c0.device_name(), list_devices()[0]["name"]);
    EXPECT_EQ(c0.validation_messages(), 0u) << joined(c0.validation_log());
  }
  for (std::string bad : {"no-such-gpu-xyz", "99"}) {
    ContextOptions o;
    o.device = bad;
    try {
      Context c(o);
      FAIL() << "device '" << bad << "' was accepted";
    } catch (const Error& e) {
      std::string msg = e.what();
      EXPECT_NE(msg.find("'" + bad + "'"), std::string::npos) << msg;
      EXPECT_NE(msg.find("available:"), std::string::npos) << msg;
      EXPECT_NE(msg.find(ctx().device_name()), std::string::npos) << msg;
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    }
  }
}

TEST_F(Gpu, DeviceFromEnvironment) {
  const std::string suite_device = std::getenv("HAZE_DEVICE") ? std::getenv("HAZE_DEVICE") : "";
  ::setenv("HAZE_DEVICE", "no-such-gpu-from-env", 1);
  EXPECT_THROW(Context{}, Error);
  ContextOptions o;
  o.device = std::to_string(ctx().device_index());  // the option wins over the environment
  EXPECT_NO_THROW(Context{o});
  ::setenv("HAZE_DEVICE", suite_device.c_str(), 1);
}

TEST_F(Gpu, MissingValidationLayerIsExplained) {
  // VK_LAYER_PATH replaces the loader's search path for explicit layers: an empty folder hides them all.
  const char* old = std::getenv("VK_LAYER_PATH");
  std::string saved = old ? old : "";
  auto empty = temp_dir() / "no_layers";
  std::filesystem::create_directories(empty);
  ::setenv("VK_LAYER_PATH", empty.c_str(), 1);
  ContextOptions o;
  o.validation = true;
  try {
    Context c(o);
    ADD_FAILURE() << "validation context created without the layer";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()),
              "validation requested but VK_LAYER_KHRONOS_validation is not installed: run scripts/setup.sh");
  }
  if (old)
    ::setenv("VK_LAYER_PATH", saved.c_str(), 1);
  else
    ::unsetenv("VK_LAYER_PATH");
}

TEST_F(Gpu, OldLavapipeIsRefused) {
  EXPECT_EQ(detail::old_lavapipe_message(VK_DRIVER_ID_MESA_LLVMPIPE, "Mesa 22.3.6 (LLVM 15.0.6)"),
            "lavapipe from Mesa 22.3 silently truncates long shader loops; install Mesa >= 24 "
            "(scripts/setup.sh installs it from bookworm-backports)");
  EXPECT_EQ(detail::old_lavapipe_message(VK_DRIVER_ID_MESA_LLVMPIPE, "Mesa 23.1.0"),
            "lavapipe from Mesa 23.1 silently truncates long shader loops; install Mesa >= 24 "
            "(scripts/setup.sh installs it from bookworm-backports)");
  EXPECT_EQ(detail::old_lavapipe_message(VK_DRIVER_ID_MESA_LLVMPIPE, "Mesa 24.0.0"), "");
  EXPECT_EQ(detail::old_lavapipe_message(VK_DRIVER_ID_MESA_LLVMPIPE, "Mesa 25.0.7 (LLVM 15.0.6)"), "");
  EXPECT_EQ(detail::old_lavapipe_message(VK_DRIVER_ID_MESA_RADV, "Mesa 22.3.6"), "");
}

TEST_F(Gpu, ReadSpirvErrorsNameTheFile) {
  const std::string missing = "/nonexistent/haze/missing_shader.spv";
  try {
    read_spirv(missing);
    FAIL() << "missing file accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
  }
  auto bad = (temp_dir() / "not_spirv.spv").string();
  {
    std::ofstream(bad) << "this is not SPIR-V at all!!";  // 28 bytes: a multiple of 4, wrong magic
  }
  try {
    read_spirv(bad);
    FAIL() << "malformed file accepted";
  } catch (const Error& e) {
    std::string msg = e.what();
    EXPECT_NE(msg.find(bad), std::string::npos) << msg;
    EXPECT_NE(msg.find("not a SPIR-V module"), std::string::npos) << msg;
  }
  EXPECT_THROW(ComputePipeline(ctx(), missing, 3, 8), Error);
  EXPECT_EQ(read_spirv(GPU_TEST_SPV)[0], 0x07230203u);
}

TEST_F(Gpu, ZeroSizeBuffer) {
  Buffer z(ctx(), "empty", "test", 0, "f32");
  EXPECT_TRUE(z.valid());
  EXPECT_EQ(z.size(), 0u);
  EXPECT_GE(z.allocated(), 4u);
  auto e = ctx().ledger().entries().back();
  EXPECT_EQ(e.name, "empty");
  EXPECT_EQ(e.requested, 0u);
  EXPECT_EQ(e.bytes, z.allocated());
  z.upload(nullptr, 0);
  EXPECT_TRUE(z.download_vector<float>().empty());
  z.fill_zero();
  AddPush push{0, 0};
  ctx().submit_and_wait([&](VkCommandBuffer cmd) { add().dispatch(cmd, {&z, &z, &z}, &push, 0); });
}

TEST_F(Gpu, OversizedBufferGivesClearError) {
  uint64_t too_big = ctx().max_allocation_size() + 1;
  try {
    Buffer huge(ctx(), "huge grid", "scene data", too_big);
    FAIL() << "buffer above maxMemoryAllocationSize accepted";
  } catch (const Error& e) {
    std::string msg = e.what();
    EXPECT_NE(msg.find("'huge grid'"), std::string::npos) << msg;
    EXPECT_NE(msg.find("maxMemoryAllocationSize"), std::string::npos) << msg;
  }
  EXPECT_EQ(format_bytes(1288490189), "1.2 GiB");
  EXPECT_EQ(format_bytes(512), "512 B");
}

TEST_F(Gpu, StagingPathRoundtrip) {
  ContextOptions o;
  o.validation = true;
  o.force_staging = true;
  Context staged(o);
  {
    auto data = random_floats(777, 4);
    Buffer b(staged, "staged", "test", data.size() * 4, "f32");
    EXPECT_FALSE(b.host_mapped());
    b.upload(data);
    EXPECT_EQ(b.download_vector<float>(), data);
    std::vector<float> two(2);
    b.download(two.data(), 8, 40);
    EXPECT_EQ(two[0], data[10]);
    EXPECT_EQ(two[1], data[11]);
    b.fill_zero();
    for (float x : b.download_vector<float>()) ASSERT_EQ(x, 0.0f);
    EXPECT_EQ(staged.ledger().entries().size(), 1u);   // the staging buffers are gone again
    EXPECT_GT(staged.ledger().peak(), b.allocated());  // but they were in the ledger
  }
  EXPECT_EQ(staged.ledger().total(), 0u);
  EXPECT_EQ(staged.validation_messages(), 0u) << joined(staged.validation_log());
}

TEST_F(Gpu, PipelineCacheFileIsWrittenAndReloaded) {
  auto path = (temp_dir() / "pipelines.cache").string();
  std::filesystem::remove(path);
  for (int round = 0; round < 2; ++round) {
    ContextOptions o;
    o.validation = true;
    o.pipeline_cache = path;
    Context c(o);
    ComputePipeline p(c, GPU_TEST_SPV, 3, sizeof(AddPush));
    EXPECT_NE(c.pipeline_cache(), VK_NULL_HANDLE);
    EXPECT_EQ(c.validation_messages(), 0u) << joined(c.validation_log());
  }
  EXPECT_TRUE(std::filesystem::exists(path));
  EXPECT_GT(std::filesystem::file_size(path), 0u);
  for (const auto& f : std::filesystem::directory_iterator(temp_dir()))
    EXPECT_EQ(f.path().string().find(".tmp."), std::string::npos) << f.path();
}

TEST_F(Gpu, NestedSubmitIsRefused) {
  EXPECT_THROW(ctx().submit_and_wait([&](VkCommandBuffer) { ctx().submit_and_wait([](VkCommandBuffer) {}); }),
               Error);
  Buffer b(ctx(), "after nested", "test", 16);
  b.fill_zero();  // the queue still works
}

TEST_F(Gpu, ValidationMessagesAreCounted) {
  // A separate context, so the shared one stays clean: usage 0 is invalid but harmless to the driver.
  ContextOptions o;
  o.validation = true;
  Context c(o);
  auto info = vk_struct<VkBufferCreateInfo>(VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO);
  info.size = 16;
  info.usage = 0;
  VkBuffer buf = VK_NULL_HANDLE;
  if (vkCreateBuffer(c.device(), &info, nullptr, &buf) == VK_SUCCESS)
    vkDestroyBuffer(c.device(), buf, nullptr);
  EXPECT_GE(c.validation_messages(), 1u);
  ASSERT_FALSE(c.validation_log().empty());
  EXPECT_NE(c.validation_log()[0].find("VUID"), std::string::npos) << c.validation_log()[0];
}

TEST_F(Gpu, ImageRoundtripRgba32f) {
  const uint32_t w = 37, h = 23;  // odd sizes: rows are tightly packed, no padding
  auto data = random_floats(w * h * 4, 5);
  Image img(ctx(), "radiance", "test", w, h, VK_FORMAT_R32G32B32A32_SFLOAT);
  EXPECT_TRUE(img.valid());
  EXPECT_NE(img.handle(), VK_NULL_HANDLE);
  EXPECT_NE(img.view(), VK_NULL_HANDLE);
  EXPECT_EQ(img.width(), w);
  EXPECT_EQ(img.height(), h);
  EXPECT_EQ(img.format(), VK_FORMAT_R32G32B32A32_SFLOAT);
  EXPECT_EQ(img.format_name(), "RGBA32F");
  EXPECT_EQ(img.bytes_per_pixel(), 16u);
  EXPECT_EQ(img.size(), uint64_t{w} * h * 16);
  EXPECT_EQ(img.name(), "radiance");
  img.upload(data);
  EXPECT_EQ(img.download_vector<float>(), data);

  img.clear();
  for (float x : img.download_vector<float>()) ASSERT_EQ(x, 0.0f);

  std::string msg = error_of([&] { img.upload(data.data(), 16); });
  EXPECT_TRUE(contains(msg, "'radiance'")) << msg;
  EXPECT_TRUE(contains(msg, "RGBA32F 37x23")) << msg;
  std::vector<float> small(4);
  EXPECT_THROW(img.download(small.data(), 16), Error);
}

TEST_F(Gpu, ImageRoundtripRgba16fAndOtherFormats) {
  const uint32_t w = 19, h = 7;
  auto halves = random_halves(w * h * 4, 6);
  Image img(ctx(), "history", "test", w, h, VK_FORMAT_R16G16B16A16_SFLOAT);
  EXPECT_EQ(img.bytes_per_pixel(), 8u);
  img.upload(halves);
  EXPECT_EQ(img.download_vector<uint16_t>(), halves);

  // One-channel float, integer and 8-bit formats move bit for bit as well.
  auto floats = random_floats(w * h, 7);
  Image r32f(ctx(), "r32f", "test", w, h, VK_FORMAT_R32_SFLOAT);
  r32f.upload(floats);
  EXPECT_EQ(r32f.download_vector<float>(), floats);
  std::vector<uint32_t> words(w * h);
  std::mt19937 rng(8);
  for (auto& x : words) x = rng();
  Image r32ui(ctx(), "r32ui", "test", w, h, VK_FORMAT_R32_UINT);
  r32ui.upload(words);
  EXPECT_EQ(r32ui.download_vector<uint32_t>(), words);
  Image rgba8(ctx(), "rgba8", "test", w, h, VK_FORMAT_R8G8B8A8_UNORM);
  EXPECT_EQ(rgba8.bytes_per_pixel(), 4u);
  rgba8.upload(words);
  EXPECT_EQ(rgba8.download_vector<uint32_t>(), words);
}

TEST_F(Gpu, ImageComputeMatchesCpu) {
  const uint32_t w = 37, h = 21;  // not multiples of the 8x8 workgroup
  ComputePipeline pipe(ctx(), GPU_TEST_IMAGE_SPV, {Slot::Image, Slot::Buffer, Slot::Image},
                       sizeof(ImagePush));
  EXPECT_EQ(pipe.local_size(), (std::array<uint32_t, 3>{8, 8, 1}));
  EXPECT_EQ(pipe.num_buffers(), 1u);
  EXPECT_EQ(pipe.slots(), (std::vector<Slot>{Slot::Image, Slot::Buffer, Slot::Image}));

  auto in = random_floats(w * h * 4, 9), weights = random_floats(w, 10);
  Image src(ctx(), "src", "test", w, h, VK_FORMAT_R32G32B32A32_SFLOAT),
      dst(ctx(), "dst", "test", w, h, VK_FORMAT_R32G32B32A32_SFLOAT);
  Buffer wbuf(ctx(), "weights", "test", w * 4, "f32");
  src.upload(in);
  wbuf.upload(weights);
  dst.upload(random_floats(w * h * 4, 11));  // stale contents, cleared in the same submission
  ImagePush push{w, h, 0.5f};
  ctx().submit_and_wait([&](VkCommandBuffer cmd) {
    dst.clear(cmd);
    compute_barrier(cmd);
    pipe.dispatch(cmd, {&src, &wbuf, &dst}, &push, div_up(w, 8), div_up(h, 8));
  });
  auto out = dst.download_vector<float>();
  ASSERT_EQ(out.size(), in.size());
  for (uint32_t y = 0; y < h; ++y)
    for (uint32_t x = 0; x < w; ++x) {
      size_t i = (size_t{y} * w + x) * 4;
      float add[4] = {float(x), float(y), push.bias, 1.0f};
      for (int c = 0; c < 4; ++c)
        ASSERT_EQ(out[i + c], in[i + c] * weights[x] + add[c]) << "x=" << x << " y=" << y << " c=" << c;
    }

  // The span overload, and the output fed back in as the next input.
  std::vector<Resource> resources = {&dst, &wbuf, &src};
  ctx().submit_and_wait(
      [&](VkCommandBuffer cmd) { pipe.dispatch(cmd, resources, &push, div_up(w, 8), div_up(h, 8)); });
  auto twice = src.download_vector<float>();
  for (uint32_t x = 0; x < w; ++x)
    ASSERT_EQ(twice[x * 4 + 3], (in[x * 4 + 3] * weights[x] + 1.0f) * weights[x] + 1.0f) << "x=" << x;
}

TEST_F(Gpu, ImageLedgerEntryIsExactAndGoesAway) {
  uint64_t before = ctx().ledger().total();
  size_t entries_before = ctx().ledger().entries().size();
  {
    Image a(ctx(), "history", "previous-frame data", 640, 360, VK_FORMAT_R16G16B16A16_SFLOAT);
    VkMemoryRequirements req;
    vkGetImageMemoryRequirements(ctx().device(), a.handle(), &req);
    ASSERT_EQ(ctx().ledger().entries().size(), entries_before + 1);
    auto e = ctx().ledger().entries().back();
    EXPECT_EQ(e.name, "history");
    EXPECT_EQ(e.category, "previous-frame data");
    EXPECT_EQ(e.format, "RGBA16F 640x360");
    EXPECT_EQ(e.bytes, req.size);
    EXPECT_EQ(e.bytes, a.allocated());
    EXPECT_EQ(e.requested, 640u * 360u * 8u);
    EXPECT_EQ(ctx().ledger().total(), before + req.size);

    Image b(std::move(a));
    EXPECT_FALSE(a.valid());  // NOLINT(bugprone-use-after-move): moved-from state is part of the contract
    Image c;
    c = std::move(b);
    EXPECT_TRUE(c.valid());
    EXPECT_EQ(c.name(), "history");
    EXPECT_EQ(c.width(), 640u);
    EXPECT_EQ(ctx().ledger().entries().size(), entries_before + 1);
  }
  EXPECT_EQ(ctx().ledger().total(), before);
  EXPECT_EQ(ctx().ledger().entries().size(), entries_before);

  // Transfers stage through a buffer that is in the ledger under "staging" only while it lives.
  ContextOptions o;
  o.validation = true;
  Context fresh(o);
  {
    Image img(fresh, "staged image", "test", 64, 32, VK_FORMAT_R32_SFLOAT);
    EXPECT_EQ(fresh.ledger().peak(), img.allocated());
    img.upload(random_floats(64 * 32, 12));
    EXPECT_GE(fresh.ledger().peak(), img.allocated() + img.size());
    ASSERT_EQ(fresh.ledger().entries().size(), 1u);
    EXPECT_EQ(fresh.ledger().per_category().count("staging"), 0u);
  }
  EXPECT_EQ(fresh.ledger().total(), 0u);
  EXPECT_EQ(fresh.validation_messages(), 0u) << joined(fresh.validation_log());
}

TEST_F(Gpu, ImageFormatAndSizeErrorsAreClear) {
  // Not in gpu::Image's table.
  std::string msg = error_of([&] { Image(ctx(), "depth", "test", 8, 8, VK_FORMAT_D32_SFLOAT); });
  EXPECT_TRUE(contains(msg, "'depth'")) << msg;
  EXPECT_TRUE(contains(msg, "VkFormat(126)")) << msg;
  EXPECT_TRUE(contains(msg, "RGBA16F")) << msg;  // lists what is supported
  // In the table, but three-channel formats are (practically) never storage images.
  VkFormatProperties fp;
  vkGetPhysicalDeviceFormatProperties(ctx().physical(), VK_FORMAT_R32G32B32_SFLOAT, &fp);
  if (!(fp.optimalTilingFeatures & VK_FORMAT_FEATURE_STORAGE_IMAGE_BIT)) {
    msg = error_of([&] { Image(ctx(), "rgb", "test", 8, 8, VK_FORMAT_R32G32B32_SFLOAT); });
    EXPECT_TRUE(contains(msg, "'rgb'")) << msg;
    EXPECT_TRUE(contains(msg, "RGB32F")) << msg;
    EXPECT_TRUE(contains(msg, "storage image")) << msg;
    EXPECT_TRUE(contains(msg, ctx().device_name())) << msg;
  }
  msg = error_of([&] { Image(ctx(), "empty", "test", 0, 8, VK_FORMAT_R32_SFLOAT); });
  EXPECT_TRUE(contains(msg, "'empty'")) << msg;
  uint32_t too_wide = ctx().limits().maxImageDimension2D + 1;
  msg = error_of([&] { Image(ctx(), "too wide", "test", too_wide, 1, VK_FORMAT_R32_SFLOAT); });
  EXPECT_TRUE(contains(msg, "'too wide'")) << msg;
  EXPECT_TRUE(contains(msg, "maxImageDimension2D")) << msg;
  EXPECT_EQ(image_format_name(VK_FORMAT_R16G16B16A16_SFLOAT), "RGBA16F");
  EXPECT_EQ(image_format_bytes(VK_FORMAT_R32_UINT), 4u);
  EXPECT_EQ(image_format_bytes(VK_FORMAT_D32_SFLOAT), 0u);
}

TEST_F(Gpu, SlotAndResourceMismatchesAreClear) {
  const std::string spv = GPU_TEST_IMAGE_SPV;
  // At creation, from the SPIR-V: an image binding declared as a buffer, a buffer as an image, too few.
  std::string msg = error_of([&] { ComputePipeline(ctx(), spv, 3, sizeof(ImagePush)); });
  EXPECT_TRUE(contains(msg, spv)) << msg;
  EXPECT_TRUE(contains(msg, "binding 0 as a storage image")) << msg;
  msg = error_of([&] { ComputePipeline(ctx(), spv, {Slot::Image, Slot::Image, Slot::Image}, 12); });
  EXPECT_TRUE(contains(msg, "binding 1 as a storage buffer")) << msg;
  msg = error_of([&] { ComputePipeline(ctx(), spv, {Slot::Image, Slot::Buffer}, 12); });
  EXPECT_TRUE(contains(msg, "binding 2")) << msg;
  msg = error_of([&] { ComputePipeline(ctx(), GPU_TEST_SPV, {Slot::Buffer, Slot::Image, Slot::Buffer}, 8); });
  EXPECT_TRUE(contains(msg, "binding 1 as a storage buffer")) << msg;

  // At dispatch: the wrong kind of resource, a format other than the shader's, the wrong count.
  ComputePipeline pipe(ctx(), spv, {Slot::Image, Slot::Buffer, Slot::Image}, sizeof(ImagePush));
  Image a(ctx(), "in", "test", 8, 8, VK_FORMAT_R32G32B32A32_SFLOAT),
      b(ctx(), "out", "test", 8, 8, VK_FORMAT_R32G32B32A32_SFLOAT),
      half(ctx(), "half out", "test", 8, 8, VK_FORMAT_R16G16B16A16_SFLOAT);
  Buffer wbuf(ctx(), "weights", "test", 8 * 4, "f32");
  wbuf.fill_zero();
  ImagePush push{8, 8, 0};
  const auto dispatch_error = [&](std::vector<Resource> res) {
    return error_of(
        [&] { ctx().submit_and_wait([&](VkCommandBuffer cmd) { pipe.dispatch(cmd, res, &push, 1, 1); }); });
  };
  msg = dispatch_error({&wbuf, &wbuf, &b});
  EXPECT_TRUE(contains(msg, spv)) << msg;
  EXPECT_TRUE(contains(msg, "binding 0 is a storage image, but got buffer 'weights'")) << msg;
  msg = dispatch_error({&a, &a, &b});
  EXPECT_TRUE(contains(msg, "binding 1 is a storage buffer, but got image 'in'")) << msg;
  msg = dispatch_error({&a, &wbuf, &half});
  EXPECT_TRUE(contains(msg, "binding 2")) << msg;
  EXPECT_TRUE(contains(msg, "RGBA32F")) << msg;
  EXPECT_TRUE(contains(msg, "'half out' is RGBA16F")) << msg;
  msg = dispatch_error({&a, &wbuf});
  EXPECT_TRUE(contains(msg, "2 resources")) << msg;
  msg = dispatch_error({&a, &wbuf, static_cast<const Image*>(nullptr)});
  EXPECT_TRUE(contains(msg, "image 2 is empty")) << msg;
  // A buffer-only pipeline refuses an image too.
  AddPush add_push{16, 0};
  msg = error_of([&] {
    ctx().submit_and_wait([&](VkCommandBuffer cmd) {
      add().dispatch(cmd, {&a, &wbuf, &wbuf}, &add_push, 1);
    });
  });
  EXPECT_TRUE(contains(msg, GPU_TEST_SPV)) << msg;
  EXPECT_TRUE(contains(msg, "binding 0 is a storage buffer, but got image 'in'")) << msg;

  // Still usable after all the refusals.
  ctx().submit_and_wait([&](VkCommandBuffer cmd) { pipe.dispatch(cmd, {&a, &wbuf, &b}, &push, 1, 1); });
}

// ---- kernels: declared in C++, compiled on demand, bound by name ----

// bench/copy.comp: dst[i] = src[i] for i < count, vec4 elements, bindings "src" and "dst".
KernelDecl copy_decl(uint32_t count, bool dst_first = false) {
  KernelDecl d("bench/copy.comp");
  if (dst_first) d.buffer("dst", uint64_t(count) * 16, 16);
  d.buffer("src", uint64_t(count) * 16, 16);
  if (!dst_first) d.buffer("dst", uint64_t(count) * 16, 16);
  return std::move(d.push(4));
}

std::vector<float> run_copy(Context& c, const Kernel& k, const Buffer& src, const Buffer& dst,
                            uint32_t count) {
  Bindings b;
  b.set("src", src).set("dst", dst);
  c.submit_and_wait([&](VkCommandBuffer cmd) { k.dispatch_1d(cmd, b, &count, count); });
  return dst.download_vector<float>();
}

TEST_F(Gpu, KernelBindingNumbersComeFromTheDeclaration) {
  const uint32_t n = 100;
  std::vector<float> v = random_floats(n * 4, 7);
  Buffer src(ctx(), "kernel src", "test", n * 16), dst(ctx(), "kernel dst", "test", n * 16);
  src.upload(v);
  // The same source with its two bindings in either order: the defines follow the declaration.
  for (bool dst_first : {false, true}) {
    Kernel k(ctx(), copy_decl(n, dst_first));
    EXPECT_EQ(k.decl().bindings()[0].name, dst_first ? "dst" : "src");
    const ShaderPermutation p = k.decl().permutation();
    EXPECT_EQ(p.defines.back().first, dst_first ? "BINDING_src" : "BINDING_dst");
    dst.fill_zero();
    EXPECT_EQ(run_copy(ctx(), k, src, dst, n), v) << (dst_first ? "dst first" : "src first");
  }
}

TEST_F(Gpu, KernelPipelineIsCreatedOncePerContext) {
  Kernel a(ctx(), copy_decl(8));
  const size_t pipelines = ctx().kernels().size();
  Kernel b(ctx(), copy_decl(64));  // other size expectations, same pipeline
  EXPECT_EQ(ctx().kernels().size(), pipelines);
  EXPECT_EQ(&a.pipeline(), &b.pipeline());
  EXPECT_EQ(b.setup_ms(), 0.0);
  Kernel c(ctx(), std::move(copy_decl(8).define("UNUSED_FEATURE")));  // another permutation
  EXPECT_EQ(ctx().kernels().size(), pipelines + 1);
  EXPECT_NE(&a.pipeline(), &c.pipeline());
}

TEST_F(Gpu, KernelBindErrorsNameTheKernelAndTheBinding) {
  const uint32_t n = 16;
  Kernel k(ctx(), copy_decl(n));
  Buffer src(ctx(), "kernel src", "test", n * 16), dst(ctx(), "kernel dst", "test", n * 16);
  Buffer small(ctx(), "small one", "test", (n - 1) * 16), odd(ctx(), "odd one", "test", n * 16 + 4);
  Image img(ctx(), "an image", "test", 4, 4, VK_FORMAT_R32G32B32A32_SFLOAT);
  auto dispatch_error = [&](const Bindings& b) {
    const uint32_t count = n;
    return error_of(
        [&] { ctx().submit_and_wait([&](VkCommandBuffer cmd) { k.dispatch(cmd, b, &count, 1); }); });
  };
  Bindings missing;
  missing.set("src", src);
  std::string msg = dispatch_error(missing);
  EXPECT_TRUE(contains(msg, "kernel bench/copy.comp [default]: binding 'dst' is not bound")) << msg;
  Bindings too_small;
  too_small.set("src", small).set("dst", dst);
  msg = dispatch_error(too_small);
  EXPECT_TRUE(contains(msg, "binding 'src' is buffer 'small one' of 240 bytes; the kernel reads 256 bytes"))
      << msg;
  Bindings ragged;
  ragged.set("src", src).set("dst", odd);
  msg = dispatch_error(ragged);
  EXPECT_TRUE(contains(msg, "binding 'dst' is buffer 'odd one' of 260 bytes, not a whole number of 16-byte"))
      << msg;
  Bindings image;
  image.set("src", img).set("dst", dst);
  msg = dispatch_error(image);
  EXPECT_TRUE(contains(msg, "binding 'src' is a storage buffer, but image 'an image' is bound there")) << msg;
  Bindings empty;
  Buffer none;
  empty.set("src", none).set("dst", dst);
  msg = dispatch_error(empty);
  EXPECT_TRUE(contains(msg, "binding 'src' is an empty buffer")) << msg;
  // Extra resources a kernel does not declare are ignored; the kernel still works after the refusals.
  Bindings extra;
  extra.set("src", src).set("dst", dst).set("unrelated", small);
  const uint32_t count = n;
  ctx().submit_and_wait([&](VkCommandBuffer cmd) { k.dispatch(cmd, extra, &count, 1); });
}

TEST_F(Gpu, KernelCompileErrorsNameShaderPermutationAndLine) {
  // Without the "dst" binding the shader's BINDING_dst is undeclared.
  KernelDecl d("bench/copy.comp");
  d.buffer("src").define("HAZE_SOMETHING").push(4);
  std::string msg = error_of([&] { Kernel k(ctx(), d); });
  EXPECT_TRUE(contains(msg, "shader bench/copy.comp [SOMETHING]: bench/copy.comp:")) << msg;
  EXPECT_TRUE(contains(msg, "BINDING_dst")) << msg;
  EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  msg = error_of([&] { Kernel k(ctx(), KernelDecl("no/such.comp")); });
  EXPECT_TRUE(contains(msg, "no such shader source 'no/such.comp'")) << msg;
  msg = error_of([&] { KernelDecl("x.comp").buffer("not a name"); });
  EXPECT_TRUE(contains(msg, "binding 'not a name' is not an identifier")) << msg;
}

// More items than maxComputeWorkGroupCount[0] groups of 64 reach along x (a 3840x2160 frame needs 129600):
// dispatch_1d spreads the groups over y, and every item, the last included, is processed once.
TEST_F(Gpu, Dispatch1dCoversMoreGroupsThanTheXLimit) {
  const uint64_t limit = ctx().limits().maxComputeWorkGroupCount[0];
  const uint32_t n = uint32_t(std::min<uint64_t>((limit + 2) * 64 + 5, 1u << 24));
  ASSERT_GT(uint64_t(n), limit * 64) << "the device allows more groups than this test can cover";
  std::vector<glm::vec4> v(n);
  for (uint32_t i = 0; i < n; ++i) v[i] = glm::vec4(float(i), float(i % 7), 1.f, -float(i));
  Buffer src(ctx(), "dispatch_1d src", "test", uint64_t(n) * 16),
      dst(ctx(), "dispatch_1d dst", "test", uint64_t(n) * 16);
  src.upload(v);
  dst.fill_zero();
  Kernel k(ctx(), copy_decl(n));
  Bindings b;
  b.set("src", src).set("dst", dst);
  ctx().submit_and_wait([&](VkCommandBuffer cmd) { k.dispatch_1d(cmd, b, &n, n); });
  std::vector<glm::vec4> got = dst.download_vector<glm::vec4>();
  size_t wrong = 0;
  for (uint32_t i = 0; i < n; ++i) wrong += got[i] != v[i];
  EXPECT_EQ(wrong, 0u);
  EXPECT_EQ(got.back(), v.back());
}

TEST_F(Gpu, PixelLayersInterleaveOnTheHost) {
  const uint64_t pixels = 5;
  PixelLayers L(ctx(), "test layers", "test", pixels, {"layer_a", "layer_b"});
  EXPECT_EQ(L.stride(), 8u);
  std::vector<float> host(pixels * 8);
  for (size_t i = 0; i < host.size(); ++i) host[i] = float(i);
  L.upload(host);
  // Layer b holds floats 4..7 of every pixel.
  std::vector<float> b = L[1].download_vector<float>();
  for (size_t p = 0; p < pixels; ++p)
    for (size_t c = 0; c < 4; ++c) EXPECT_EQ(b[p * 4 + c], float(p * 8 + 4 + c));
  EXPECT_EQ(L.download(), host);
  KernelDecl d("bench/copy.comp");
  L.declare(d);
  ASSERT_EQ(d.bindings().size(), 2u);
  EXPECT_EQ(d.bindings()[1].name, "layer_b");
  EXPECT_EQ(d.bindings()[1].min_bytes, pixels * 16);
}

}  // namespace
}  // namespace haze::gpu
