// The GPU layer on whatever device the environment pins (lavapipe under ctest), validation on.
#include "gpu/gpu.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>

namespace haze::gpu {
namespace {

#ifndef GPU_TEST_SPV
#error "GPU_TEST_SPV (path of gpu_test_add.spv) must be defined by the build"
#endif

struct AddPush {
  uint32_t n;
  float k;
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
};

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
  ::setenv("HAZE_DEVICE", "no-such-gpu-from-env", 1);
  EXPECT_THROW(Context{}, Error);
  ContextOptions o;
  o.device = "0";  // the option wins over the environment
  EXPECT_NO_THROW(Context{o});
  ::unsetenv("HAZE_DEVICE");
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

}  // namespace
}  // namespace haze::gpu
