#include "view/viewer.hpp"

#define GLFW_INCLUDE_VULKAN
#include <GLFW/glfw3.h>
#include <fmt/format.h>
#include <imgui.h>
#include <imgui_stdlib.h>

#include <algorithm>
#include <chrono>
#include <deque>
#include <map>
#include <memory>
#include <optional>

#include "gpu/gpu.hpp"
#include "gpu/swapchain.hpp"
#include "render/output.hpp"
#include "render/renderer.hpp"
#include "render/run.hpp"
#include "view/camera.hpp"
#include "view/layers.hpp"
#include "view/panel.hpp"
#include "view/script.hpp"
#include "view/ui.hpp"
#include "view/window.hpp"

namespace haze::view {
namespace {

using clock = std::chrono::steady_clock;

constexpr int kPanelWidth = 420;
constexpr uint32_t kFramesInFlight = 2;
constexpr int kMaxSamplesPerFrame = 256;  // one timer scope each (the ring's frames time 512)
constexpr size_t kGraphFrames = 120;

double ms_between(clock::time_point a, clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// "svgf.surface.filter2" -> "svgf.surface"; "view.display" -> "view"; others as they are.
std::string pass_group(const std::string& pass) {
  if (pass.rfind("svgf.", 0) == 0) return pass.substr(0, pass.find('.', 5));
  if (pass.rfind("view.", 0) == 0) return "view";
  return pass;
}

// The scene's size: the box around its media and surfaces (the camera and haze boxes do not count).
float extent_of(const render::Renderer& r) {
  glm::vec3 lo(1e30f), hi(-1e30f);
  for (const auto& m : r.media().media) {
    lo = glm::min(lo, glm::vec3(m.world_min));
    hi = glm::max(hi, glm::vec3(m.world_max));
  }
  for (const auto& t : r.geometry().bvh.triangles) {
    for (const glm::vec4* v : {&t.v0, &t.v1, &t.v2}) {
      lo = glm::min(lo, glm::vec3(*v));
      hi = glm::max(hi, glm::vec3(*v));
    }
  }
  return scene_extent(lo, hi);
}

// The frame's 8-bit image as a transfer source for the (scaled) blit into the window: copied into in
// TRANSFER_DST_OPTIMAL, read in TRANSFER_SRC_OPTIMAL, every frame anew.
class TransferImage {
 public:
  TransferImage() = default;
  TransferImage(gpu::Context& ctx, uint32_t width, uint32_t height)
      : ctx_(&ctx), width_(width), height_(height) {
    auto info = gpu::vk_struct<VkImageCreateInfo>(VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO);
    info.imageType = VK_IMAGE_TYPE_2D;
    info.format = VK_FORMAT_R8G8B8A8_UNORM;
    info.extent = {width, height, 1};
    info.mipLevels = 1;
    info.arrayLayers = 1;
    info.samples = VK_SAMPLE_COUNT_1_BIT;
    info.tiling = VK_IMAGE_TILING_OPTIMAL;
    info.usage = VK_IMAGE_USAGE_TRANSFER_SRC_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
    info.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
    HAZE_VK(vkCreateImage(ctx.device(), &info, nullptr, &image_));
    VkMemoryRequirements req;
    vkGetImageMemoryRequirements(ctx.device(), image_, &req);
    const auto& mp = ctx.memory_properties();
    uint32_t type = UINT32_MAX;
    for (uint32_t i = 0; i < mp.memoryTypeCount && type == UINT32_MAX; ++i)
      if ((req.memoryTypeBits & (1u << i)) &&
          (mp.memoryTypes[i].propertyFlags & VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT))
        type = i;
    for (uint32_t i = 0; i < mp.memoryTypeCount && type == UINT32_MAX; ++i)
      if (req.memoryTypeBits & (1u << i)) type = i;
    auto ainfo = gpu::vk_struct<VkMemoryAllocateInfo>(VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO);
    ainfo.allocationSize = req.size;
    ainfo.memoryTypeIndex = type;
    HAZE_VK(vkAllocateMemory(ctx.device(), &ainfo, nullptr, &memory_));
    HAZE_VK(vkBindImageMemory(ctx.device(), image_, memory_, 0));
    ledger_id_ =
        ctx.ledger().add({"view display image", "viewer", "RGBA8", req.size, uint64_t(width) * height * 4});
  }
  ~TransferImage() { release(); }
  TransferImage(TransferImage&& o) noexcept { *this = std::move(o); }
  TransferImage& operator=(TransferImage&& o) noexcept {
    if (this != &o) {
      release();
      std::swap(ctx_, o.ctx_);
      std::swap(image_, o.image_);
      std::swap(memory_, o.memory_);
      std::swap(ledger_id_, o.ledger_id_);
      width_ = o.width_;
      height_ = o.height_;
    }
    return *this;
  }
  VkImage handle() const { return image_; }
  uint32_t width() const { return width_; }
  uint32_t height() const { return height_; }

 private:
  void release() noexcept {
    if (!ctx_) return;
    try {
      ctx_->wait_in_flight();
    } catch (...) {
    }
    if (image_) vkDestroyImage(ctx_->device(), image_, nullptr);
    if (memory_) vkFreeMemory(ctx_->device(), memory_, nullptr);
    ctx_->ledger().remove(ledger_id_);
    ctx_ = nullptr;
    image_ = VK_NULL_HANDLE;
    memory_ = VK_NULL_HANDLE;
  }
  gpu::Context* ctx_ = nullptr;
  VkImage image_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  uint64_t ledger_id_ = 0;
  uint32_t width_ = 0, height_ = 0;
};

struct FrameRecord {
  int frame = 0;
  double wall_ms = 0;                     // since the previous present
  double acquire_ms = 0, present_ms = 0;  // the host inside vkAcquireNextImageKHR and vkQueuePresentKHR
  double gpu_ms = -1;                     // every timed pass of the frame; arrives a frame late
  int samples = 0;
  bool compiling = false;
  std::string layer;
};

class Viewer {
 public:
  Viewer(const scene::Scene& s, const ViewOptions& o, const gpu::ContextOptions& co);
  ~Viewer();
  ViewRun run();

 private:
  void apply(const scene::Scene& next, bool camera_only);
  bool try_apply(const scene::Scene& next);
  void restore();
  void make_display();
  void recreate_swapchain();
  void handle_input(double dt);
  void draw_ui();
  void frame(int n);
  void present_previous();
  void save_scene(const std::string& path) const;
  nlohmann::json run_stats() const;

  ViewOptions o_;
  std::vector<ScriptStep> script_;
  size_t next_step_ = 0;
  int scale_ = 1;

  std::unique_ptr<Window> window_;
  std::unique_ptr<gpu::Context> ctx_;
  std::unique_ptr<gpu::Swapchain> swapchain_;
  std::unique_ptr<render::Renderer> renderer_;
  std::unique_ptr<LayerDisplay> layers_;
  std::unique_ptr<Ui> ui_;
  gpu::Buffer display_;
  TransferImage display_image_;
  std::vector<VkSemaphore> acquired_, rendered_;
  std::unique_ptr<gpu::FrameRing> ring_;  // destroyed first: its frames use everything above

  scene::Scene scene_;                   // what the renderer renders
  std::optional<scene::Scene> pending_;  // waits for its kernels
  uint32_t frame_ = 0;                   // the renderer's frame number (noise seed), one per change
  std::unique_ptr<CameraController> camera_;
  CameraMode mode_ = CameraMode::Fly;
  float extent_ = 1;
  std::string layer_;
  bool ui_visible_ = true;
  std::string error_, status_;
  bool scripted_ = false;

  std::vector<gpu::TimerScope> last_scopes_;
  std::vector<FrameRecord> records_;
  std::deque<std::map<std::string, double>> graph_;
  clock::time_point last_present_{};
  std::optional<std::pair<uint32_t, size_t>> unpresented_;  // submitted, not yet presented: image, record
  std::optional<glm::dvec2> last_cursor_;
  std::string screenshot_now_, save_image_now_;
  int frames_while_compiling_ = 0, compiles_ = 0;
};

Viewer::Viewer(const scene::Scene& s, const ViewOptions& o, const gpu::ContextOptions& co) : o_(o) {
  if (o.spp < 1 || o.spp > kMaxSamplesPerFrame)
    throw std::runtime_error(
        fmt::format("--spp {}: samples per frame must be in [1, {}]", o.spp, kMaxSamplesPerFrame));
  if (o.frames < 0) throw std::runtime_error(fmt::format("--frames {}: must be >= 0", o.frames));
  if (!o.script.empty() && o.frames == 0)
    throw std::runtime_error("--script needs --frames N: a scripted run ends after N frames");
  const std::vector<std::string> names = layer_names();
  if (std::find(names.begin(), names.end(), o.layer) == names.end())
    throw std::runtime_error(
        fmt::format("--layer {}: not a layer; one of {}", o.layer, fmt::join(names, ", ")));
  scene_ = s;
  scene_.animation.reset();  // the viewer shows one frame; saved scenes hold that frame's state
  scripted_ = o.frames > 0;
  if (!o.script.empty()) script_ = load_script(o.script, scene_, o.frames, names);
  layer_ = o.layer;
  ui_visible_ = o.ui;

  const int w = scene_.render.width, h = scene_.render.height;
  scale_ = o.scale > 0 ? o.scale : std::max(1, std::min(960 / w, 720 / h));
  window_ = std::make_unique<Window>(w * scale_ + kPanelWidth, std::max(h * scale_, 720), "haze view");
  gpu::ContextOptions wo = co;
  wo.instance_extensions = window_->instance_extensions();
  wo.device_extensions = {VK_KHR_SWAPCHAIN_EXTENSION_NAME};
  wo.graphics = true;
  ctx_ = std::make_unique<gpu::Context>(wo);
  const glm::ivec2 fb = window_->framebuffer_size();
  swapchain_ = std::make_unique<gpu::Swapchain>(*ctx_, window_->surface(ctx_->instance()), uint32_t(fb.x),
                                                uint32_t(fb.y));
  ui_ = std::make_unique<Ui>(*ctx_, *window_, *swapchain_, kFramesInFlight);
  auto semaphore = [&] {
    auto info = gpu::vk_struct<VkSemaphoreCreateInfo>(VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO);
    VkSemaphore sem = VK_NULL_HANDLE;
    HAZE_VK(vkCreateSemaphore(ctx_->device(), &info, nullptr, &sem));
    return sem;
  };
  for (uint32_t i = 0; i < kFramesInFlight; ++i) acquired_.push_back(semaphore());
  for (uint32_t i = 0; i < swapchain_->image_count(); ++i) rendered_.push_back(semaphore());

  // The first state's kernels are compiled before the first frame; later ones in the background.
  render::check_part_specs(scene_);
  renderer_ = std::make_unique<render::Renderer>(*ctx_, scene_, frame_);
  for (const auto& n : renderer_->notes()) fmt::print(stderr, "note: {}\n", n);
  layers_ = std::make_unique<LayerDisplay>(*ctx_);
  ctx_->kernels().set_deferred(true);
  extent_ = extent_of(*renderer_);
  camera_ = std::make_unique<CameraController>(scene_.camera, extent_);
  make_display();
  ring_ = std::make_unique<gpu::FrameRing>(*ctx_, "viewer", kFramesInFlight, 512);
  ring_->on_times([this](const std::vector<gpu::TimerScope>& t) { last_scopes_ = t; });
}

Viewer::~Viewer() {
  ring_.reset();
  ui_.reset();
  if (ctx_) {
    vkDeviceWaitIdle(ctx_->device());
    for (VkSemaphore s : acquired_) vkDestroySemaphore(ctx_->device(), s, nullptr);
    for (VkSemaphore s : rendered_) vkDestroySemaphore(ctx_->device(), s, nullptr);
  }
  swapchain_.reset();
  display_ = gpu::Buffer();
  display_image_ = TransferImage();
  layers_.reset();
  renderer_.reset();
  if (window_) window_->destroy_surface();
  ctx_.reset();
  window_.reset();
}

void Viewer::make_display() {
  const auto& r = renderer_->scene().render;
  const uint64_t pixels = uint64_t(r.width) * uint64_t(r.height);
  display_ = gpu::Buffer(*ctx_, "view display", "viewer", pixels * 4, "RGBA8");
  display_image_ = TransferImage(*ctx_, uint32_t(r.width), uint32_t(r.height));
}

void Viewer::recreate_swapchain() {
  present_previous();
  glm::ivec2 fb = window_->framebuffer_size();
  while (fb.x == 0 || fb.y == 0) {  // minimised
    glfwWaitEvents();
    fb = window_->framebuffer_size();
  }
  ring_->finish();
  swapchain_->recreate(uint32_t(fb.x), uint32_t(fb.y));
  ui_->recreate(*swapchain_);
  for (VkSemaphore s : rendered_) vkDestroySemaphore(ctx_->device(), s, nullptr);
  rendered_.clear();
  for (uint32_t i = 0; i < swapchain_->image_count(); ++i) {
    auto info = gpu::vk_struct<VkSemaphoreCreateInfo>(VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO);
    VkSemaphore sem = VK_NULL_HANDLE;
    HAZE_VK(vkCreateSemaphore(ctx_->device(), &info, nullptr, &sem));
    rendered_.push_back(sem);
  }
}

// The renderer takes `next`; a state whose kernels are still compiling waits (pending_) while the old
// state keeps rendering with the old kernels.
bool Viewer::try_apply(const scene::Scene& next) {
  const uint64_t misses = ctx_->kernels().misses();
  try {
    renderer_->set_scene(next, frame_ + 1, &scene_);
  } catch (const std::exception& e) {
    error_ = e.what();
    pending_.reset();
    restore();
    return false;
  }
  if (ctx_->kernels().misses() > misses) {
    if (!pending_) ++compiles_;
    pending_ = next;
    restore();
    return false;
  }
  scene_ = next;
  ++frame_;
  pending_.reset();
  error_.clear();
  return true;
}

// Back to scene_ (its kernels exist): the parts are updated again, the accumulation restarts.
void Viewer::restore() {
  renderer_->set_scene(scene_, ++frame_, &scene_);
}

void Viewer::apply(const scene::Scene& next, bool camera_only) {
  if (camera_only && !pending_) {
    renderer_->set_camera(next.camera, scene_.camera, ++frame_);
    scene_.camera = next.camera;
    return;
  }
  if (camera_only && pending_) {
    pending_->camera = next.camera;
    renderer_->set_camera(next.camera, scene_.camera, ++frame_);
    scene_.camera = next.camera;
    return;
  }
  try_apply(next);
}

void Viewer::handle_input(double dt) {
  ImGuiIO& io = ImGui::GetIO();
  GLFWwindow* w = window_->handle();
  CameraInput in;
  in.dt = dt;
  if (!io.WantCaptureKeyboard) {
    auto key = [&](int k) { return glfwGetKey(w, k) == GLFW_PRESS ? 1.f : 0.f; };
    in.move = glm::vec3(key(GLFW_KEY_D) - key(GLFW_KEY_A), key(GLFW_KEY_E) - key(GLFW_KEY_Q),
                        key(GLFW_KEY_W) - key(GLFW_KEY_S));
    in.fast = key(GLFW_KEY_LEFT_SHIFT) > 0 || key(GLFW_KEY_RIGHT_SHIFT) > 0;
    if (ImGui::IsKeyPressed(ImGui::GetKeyIndex(ImGuiKey_Tab)))
      mode_ = mode_ == CameraMode::Fly ? CameraMode::Orbit : CameraMode::Fly;
    if (ImGui::IsKeyPressed(ImGui::GetKeyIndex(ImGuiKey_Escape))) glfwSetWindowShouldClose(w, GLFW_TRUE);
    if (ImGui::IsKeyPressed('H')) ui_visible_ = !ui_visible_;
  }
  double x = 0, y = 0;
  glfwGetCursorPos(w, &x, &y);
  const bool dragging =
      !io.WantCaptureMouse && (glfwGetMouseButton(w, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS ||
                               glfwGetMouseButton(w, GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS);
  if (dragging && last_cursor_) in.look = glm::vec2(glm::dvec2(x, y) - *last_cursor_);
  last_cursor_ = dragging ? std::optional<glm::dvec2>(glm::dvec2(x, y)) : std::nullopt;
  if (!io.WantCaptureMouse) in.zoom = io.MouseWheel;
  camera_->set(pending_ ? pending_->camera : scene_.camera);
  if (camera_->update(in, mode_)) {
    scene::Scene next = pending_ ? *pending_ : scene_;
    next.camera = camera_->camera();
    apply(next, true);
  }
}

void Viewer::draw_ui() {
  const glm::ivec2 fb = window_->framebuffer_size();
  ImGui::SetNextWindowPos(ImVec2(float(fb.x - kPanelWidth), 0));
  ImGui::SetNextWindowSize(ImVec2(float(kPanelWidth), float(fb.y)));
  ImGui::Begin("haze", nullptr,
               ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoCollapse);
  // What a researcher looks at first: speed, samples, what is compiling.
  double fps = 0;
  {
    double sum = 0;
    int n = 0;
    for (auto it = records_.rbegin(); it != records_.rend() && n < 30; ++it, ++n) sum += it->wall_ms;
    fps = n > 0 && sum > 0 ? 1000.0 * n / sum : 0;
  }
  ImGui::Text("%.2f frames/s   %d spp   state %u", fps, renderer_->samples(), frame_);
  ImGui::Text("%s, %s", ctx_->device_name().c_str(),
              mode_ == CameraMode::Fly ? "fly (Tab: orbit)" : "orbit (Tab: fly)");
  const std::vector<std::string> compiling = ctx_->kernels().compiling();
  if (pending_ || !compiling.empty()) {
    ImGui::TextColored(ImVec4(1, 0.8f, 0.3f, 1), "compiling %zu kernel%s; showing the previous state",
                       compiling.size(), compiling.size() == 1 ? "" : "s");
    for (const auto& c : compiling) ImGui::TextDisabled("  %s", c.c_str());
  }
  if (!error_.empty()) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "%s", error_.c_str());
  if (!status_.empty()) ImGui::TextDisabled("%s", status_.c_str());

  if (ImGui::BeginCombo("layer", layer_.c_str())) {
    for (const auto& l : layers()) {
      if (!LayerDisplay::available(*renderer_, l.name)) continue;
      if (ImGui::Selectable(l.name.c_str(), l.name == layer_)) layer_ = l.name;
      if (ImGui::IsItemHovered()) ImGui::SetTooltip("%s", l.help.c_str());
    }
    ImGui::EndCombo();
  }

  if (ImGui::CollapsingHeader("GPU time per pass", ImGuiTreeNodeFlags_DefaultOpen)) {
    // Stacked areas over the last frames, one colour per pass group.
    std::vector<std::string> groups;
    double top = 1e-3;
    for (const auto& f : graph_) {
      double sum = 0;
      for (const auto& [g, ms] : f) {
        sum += ms;
        if (std::find(groups.begin(), groups.end(), g) == groups.end()) groups.push_back(g);
      }
      top = std::max(top, sum);
    }
    std::sort(groups.begin(), groups.end());
    const ImVec2 size(float(kPanelWidth - 30), 110);
    const ImVec2 p0 = ImGui::GetCursorScreenPos();
    ImDrawList* dl = ImGui::GetWindowDrawList();
    dl->AddRectFilled(p0, ImVec2(p0.x + size.x, p0.y + size.y), IM_COL32(25, 25, 30, 255));
    auto colour = [&](size_t i) {
      float r, g, b;
      ImGui::ColorConvertHSVtoRGB(float(i) / float(std::max<size_t>(groups.size(), 1)), 0.6f, 0.9f, r, g, b);
      return ImGui::ColorConvertFloat4ToU32(ImVec4(r, g, b, 1));
    };
    const float dx = size.x / float(kGraphFrames);
    for (size_t fi = 0; fi < graph_.size(); ++fi) {
      float y = p0.y + size.y;
      const float x0 = p0.x + dx * float(kGraphFrames - graph_.size() + fi);
      for (size_t gi = 0; gi < groups.size(); ++gi) {
        auto it = graph_[fi].find(groups[gi]);
        if (it == graph_[fi].end()) continue;
        const float hpx = float(it->second / top) * size.y;
        dl->AddRectFilled(ImVec2(x0, y - hpx), ImVec2(x0 + dx, y), colour(gi));
        y -= hpx;
      }
    }
    ImGui::Dummy(size);
    ImGui::Text("top of the graph: %.1f ms; ms per frame, mean of the last %zu:", top, graph_.size());
    for (size_t gi = 0; gi < groups.size(); ++gi) {
      double sum = 0;
      for (const auto& f : graph_)
        if (auto it = f.find(groups[gi]); it != f.end()) sum += it->second;
      const double mean = graph_.empty() ? 0 : sum / double(graph_.size());
      ImGui::TextColored(ImGui::ColorConvertU32ToFloat4(colour(gi)), "%-16s %8.2f ms", groups[gi].c_str(),
                         mean);
    }
  }
  if (ImGui::CollapsingHeader("Memory", ImGuiTreeNodeFlags_DefaultOpen)) {
    const auto& ledger = ctx_->ledger();
    const uint64_t total = std::max<uint64_t>(ledger.total(), 1);
    const std::map<std::string, uint64_t> per_category = ledger.per_category();  // a copy: iterate one
    std::vector<std::pair<std::string, uint64_t>> cats(per_category.begin(), per_category.end());
    std::sort(cats.begin(), cats.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
    ImGui::Text("%.2f MB (peak %.2f MB)", double(ledger.total()) / 1e6, double(ledger.peak()) / 1e6);
    for (const auto& [name, bytes] : cats) {
      ImGui::ProgressBar(float(double(bytes) / double(total)), ImVec2(120, 0),
                         fmt::format("{:.2f} MB", bytes / 1e6).c_str());
      ImGui::SameLine();
      ImGui::TextUnformatted(name.c_str());
    }
  }
  if (ImGui::CollapsingHeader("Save")) {
    static std::string scene_path = "view_scene.json", image_dir = "view_image";
    ImGui::InputText("scene file", &scene_path);
    if (ImGui::Button("Save scene")) {
      try {
        save_scene(scene_path);
        status_ = "wrote " + scene_path;
      } catch (const std::exception& e) {
        error_ = e.what();
      }
    }
    ImGui::InputText("image folder", &image_dir);
    if (ImGui::Button("Save image")) save_image_now_ = image_dir;
  }
  if (ImGui::CollapsingHeader("Scene parameters", ImGuiTreeNodeFlags_DefaultOpen)) {
    scene::Scene edited = pending_ ? *pending_ : scene_;
    const PanelEdit e = draw_parameters(edited);
    if (e.changed) {
      try {
        apply(check_edit(edited), e.camera_only);
      } catch (const std::exception& ex) {
        error_ = ex.what();  // the reader's one line; nothing is applied
      }
    }
  }
  ImGui::End();
}

void Viewer::save_scene(const std::string& path) const {
  // The seed of the frame on screen: `haze render` of the file (frame 0) takes the same samples.
  scene::Scene s = scene_;
  s.render.seed = scene_.render.seed ^ (frame_ * 0x9e3779b9u);
  s.render.spp = std::max(renderer_->samples(), 1);
  render::write_json(path, scene::to_json(s));
}

void Viewer::frame(int n) {
  VkCommandBuffer cmd = ring_->begin();
  const uint32_t slot = uint32_t(ring_->submitted() % ring_->frames());
  uint32_t image = 0;
  const auto t_acquire = clock::now();
  const bool acquired = swapchain_->acquire(acquired_[slot], &image);
  const double acquire_ms = ms_between(t_acquire, clock::now());
  if (!acquired) {
    ring_->submit();  // an empty frame
    recreate_swapchain();
    return;
  }
  gpu::Timer& t = ring_->timer();
  const auto& size = renderer_->scene().render;
  if (display_image_.width() != uint32_t(size.width) || display_image_.height() != uint32_t(size.height))
    make_display();
  renderer_->record_samples(cmd, &t, o_.spp);
  renderer_->record_resolve(cmd, &t);
  if (!LayerDisplay::available(*renderer_, layer_)) layer_ = "final";
  layers_->record(cmd, &t, *renderer_, layer_, extent_, display_);

  // The frame's image into the window: display buffer -> image -> (scaled) swapchain image.
  t.begin(cmd, "view.present_copy");
  gpu::compute_barrier(cmd);
  auto barrier = gpu::vk_struct<VkImageMemoryBarrier>(VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER);
  barrier.srcQueueFamilyIndex = barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
  barrier.subresourceRange = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
  barrier.image = display_image_.handle();
  barrier.oldLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  barrier.newLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
  barrier.dstAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 0, nullptr, 0,
                       nullptr, 1, &barrier);
  VkBufferImageCopy bic{};
  bic.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  bic.imageExtent = {display_image_.width(), display_image_.height(), 1};
  vkCmdCopyBufferToImage(cmd, display_.handle(), display_image_.handle(),
                         VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &bic);
  barrier.oldLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
  barrier.newLayout = VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL;
  barrier.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  barrier.dstAccessMask = VK_ACCESS_TRANSFER_READ_BIT;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 0, nullptr, 0,
                       nullptr, 1, &barrier);
  VkImage target = swapchain_->image(image);
  barrier.image = target;
  barrier.oldLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  barrier.newLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
  barrier.srcAccessMask = 0;
  barrier.dstAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 0, nullptr, 0,
                       nullptr, 1, &barrier);
  VkClearColorValue black{};
  black.float32[3] = 1.f;
  const VkImageSubresourceRange all{VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1};
  vkCmdClearColorImage(cmd, target, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, &black, 1, &all);
  auto mem = gpu::vk_struct<VkMemoryBarrier>(VK_STRUCTURE_TYPE_MEMORY_BARRIER);
  mem.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  mem.dstAccessMask = VK_ACCESS_TRANSFER_READ_BIT | VK_ACCESS_TRANSFER_WRITE_BIT;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1, &mem, 0,
                       nullptr, 0, nullptr);
  const VkExtent2D ext = swapchain_->extent();
  VkImageBlit blit{};
  blit.srcSubresource = blit.dstSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  blit.srcOffsets[1] = {int32_t(display_image_.width()), int32_t(display_image_.height()), 1};
  blit.dstOffsets[1] = {std::min(int32_t(display_image_.width()) * scale_, int32_t(ext.width)),
                        std::min(int32_t(display_image_.height()) * scale_, int32_t(ext.height)), 1};
  vkCmdBlitImage(cmd, display_image_.handle(), VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, target,
                 VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &blit, VK_FILTER_NEAREST);
  t.end(cmd);
  t.begin(cmd, "view.ui");
  ui_->record(cmd, image, ui_visible_);
  t.end(cmd);

  // What waits for this frame: a screenshot of the window, the frame's outputs, its times.
  std::string screenshot = screenshot_now_;
  if (!screenshot.empty() && swapchain_->readable()) {
    auto shot = std::make_shared<gpu::Buffer>(gpu::Buffer::host_visible(
        *ctx_, "view screenshot", "viewer", uint64_t(ext.width) * ext.height * 4, "window pixels"));
    barrier.oldLayout = VK_IMAGE_LAYOUT_PRESENT_SRC_KHR;
    barrier.newLayout = VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL;
    barrier.srcAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
    barrier.dstAccessMask = VK_ACCESS_TRANSFER_READ_BIT;
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT,
                         0, 0, nullptr, 0, nullptr, 1, &barrier);
    VkBufferImageCopy copy{};
    copy.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
    copy.imageExtent = {ext.width, ext.height, 1};
    vkCmdCopyImageToBuffer(cmd, target, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, shot->handle(), 1, &copy);
    barrier.oldLayout = VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL;
    barrier.newLayout = VK_IMAGE_LAYOUT_PRESENT_SRC_KHR;
    barrier.srcAccessMask = VK_ACCESS_TRANSFER_READ_BIT;
    barrier.dstAccessMask = 0;
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, 0, 0,
                         nullptr, 0, nullptr, 1, &barrier);
    const bool bgra =
        swapchain_->format() == VK_FORMAT_B8G8R8A8_UNORM || swapchain_->format() == VK_FORMAT_B8G8R8A8_SRGB;
    ring_->on_complete([shot, screenshot, ext, bgra] {
      std::vector<uint32_t> px(size_t(ext.width) * ext.height);
      shot->read_mapped(px.data(), px.size() * 4);
      if (bgra)
        for (uint32_t& p : px) p = (p & 0xff00ff00u) | ((p & 0xffu) << 16) | ((p >> 16) & 0xffu);
      render::write_png_rgb8(screenshot, int(ext.width), int(ext.height), px);
    });
  } else if (!screenshot.empty()) {
    throw std::runtime_error(
        fmt::format("cannot write {}: this device's window images cannot be copied out", screenshot));
  }
  screenshot_now_.clear();
  if (!save_image_now_.empty()) {
    std::function<render::Image()> read = renderer_->record_image(cmd);
    const std::string dir = save_image_now_;
    nlohmann::json st = renderer_->stats();
    st["scene"] = scene::to_json(scene_);
    ring_->on_complete([read, dir, st, n]() mutable {
      render::Image img = read();
      render::OutputSet outs(dir);
      const std::string stem = fmt::format("frame_{:04d}", n);
      render::write_exr(outs.stage(stem + ".exr"), img);
      render::write_png(outs.stage(stem + ".png"), img);
      st["samples"] = img.samples;
      render::write_json(outs.stage("stats.json"), st);
      outs.commit();
    });
    status_ = "writing " + dir;
    save_image_now_.clear();
  }
  const size_t record = records_.size();
  ring_->on_complete([this, record] {
    double gpu = 0;
    std::map<std::string, double> groups;
    std::vector<gpu::TimerScope> renderer_scopes;
    for (const auto& s : last_scopes_) {
      const double ms = s.end_ms - s.begin_ms;
      gpu += ms;
      groups[pass_group(s.pass)] += ms;
      if (s.pass.rfind("view.", 0) != 0) renderer_scopes.push_back(s);
    }
    renderer_->add_pass_times(renderer_scopes);
    records_[record].gpu_ms = gpu;
    graph_.push_back(std::move(groups));
    if (graph_.size() > kGraphFrames) graph_.pop_front();
  });

  FrameRecord rec;
  rec.frame = n;
  rec.samples = renderer_->samples();
  rec.compiling = pending_.has_value();
  rec.layer = layer_;
  records_.push_back(rec);
  if (pending_) ++frames_while_compiling_;

  VkSemaphore wait = acquired_[slot];
  const VkPipelineStageFlags stage = VK_PIPELINE_STAGE_TRANSFER_BIT;
  ring_->submit({&wait, 1}, {&stage, 1}, {&rendered_[image], 1});
  records_.back().acquire_ms = acquire_ms;
  // The previous frame is presented now, after this one was submitted: a driver whose present waits for
  // the frame (lavapipe's X11 path copies it on the CPU) then waits while this frame is already queued, and
  // the host's work on the next frame overlaps this one on the device.
  present_previous();
  unpresented_ = {image, records_.size() - 1};
}

void Viewer::present_previous() {
  if (!unpresented_) return;
  const auto [image, record] = *unpresented_;
  unpresented_.reset();
  const auto t_present = clock::now();
  const bool ok = swapchain_->present(image, rendered_[image]);
  const auto now = clock::now();
  records_[record].present_ms = ms_between(t_present, now);
  records_[record].wall_ms = last_present_ == clock::time_point{} ? 0 : ms_between(last_present_, now);
  last_present_ = now;
  if (!ok) recreate_swapchain();
}

nlohmann::json Viewer::run_stats() const {
  nlohmann::json frames = nlohmann::json::array();
  for (const auto& r : records_)
    frames.push_back({{"frame", r.frame},
                      {"wall_ms", r.wall_ms},
                      {"acquire_ms", r.acquire_ms},
                      {"present_ms", r.present_ms},
                      {"gpu_ms", r.gpu_ms},
                      {"samples", r.samples},
                      {"compiling", r.compiling},
                      {"layer", r.layer}});
  nlohmann::json j;
  j["frames"] = frames;
  j["frames_in_flight"] = kFramesInFlight;
  j["samples_per_frame"] = o_.spp;
  j["permutation_changes"] = compiles_;
  j["frames_while_compiling"] = frames_while_compiling_;
  j["deferred_compiles"] = ctx_->kernels().deferred_compiles();
  j["host_wait_ms"] = ring_->wait_ms();
  j["host_waits_for_memory"] = ctx_->host_waits();
  j["window"] = {swapchain_->extent().width, swapchain_->extent().height};
  j["scale"] = scale_;
  j["present_mode"] = int(swapchain_->present_mode());
  j["renderer"] = renderer_->stats();
  j["scene"] = scene::to_json(scene_);
  return j;
}

ViewRun Viewer::run() {
  auto last = clock::now();
  for (int n = 0; o_.frames == 0 || n < o_.frames; ++n) {
    window_->poll();
    if (!scripted_ && window_->should_close()) break;
    // The script's entries for this frame: state first, then what happens after the frame.
    std::vector<const ScriptStep*> after;
    while (next_step_ < script_.size() && script_[next_step_].entry.frame == n) {
      const ScriptStep& st = script_[next_step_++];
      if (st.scene_changed) {
        apply(st.scene, st.camera_only);
        if (!error_.empty()) throw std::runtime_error(fmt::format("{}: {}", st.where, error_));
      }
      if (st.ui) ui_visible_ = *st.ui;
      if (!st.entry.layer.empty()) {
        if (!LayerDisplay::available(*renderer_, st.entry.layer))
          throw std::runtime_error(fmt::format("{}.layer: \"{}\" is not available in this scene at frame {}",
                                               st.where, st.entry.layer, n));
        layer_ = st.entry.layer;
      }
      if (!st.entry.screenshot.empty()) screenshot_now_ = st.entry.screenshot;
      if (!st.entry.save_image.empty()) save_image_now_ = st.entry.save_image;
      after.push_back(&st);
    }
    if (pending_ && ctx_->kernels().pending() == 0) try_apply(*pending_);
    if (scripted_ && pending_ && !error_.empty()) throw std::runtime_error(error_);
    const auto now = clock::now();
    const double dt = std::chrono::duration<double>(now - last).count();
    last = now;
    ui_->new_frame();
    if (!scripted_) handle_input(dt);
    if (ui_visible_) draw_ui();
    if (n + 1 == o_.frames && !o_.screenshot.empty()) screenshot_now_ = o_.screenshot;
    frame(n);
    for (const ScriptStep* st : after)
      if (!st->entry.save_scene.empty()) save_scene(st->entry.save_scene);
    ring_->poll();
  }
  present_previous();
  ring_->finish();
  ViewRun run;
  run.stats = run_stats();
  if (!o_.stats.empty()) render::write_json(o_.stats, run.stats);
  run.validation_messages = ctx_->validation_messages();
  return run;
}

}  // namespace

ViewRun run_view(const scene::Scene& s, const ViewOptions& o, const gpu::ContextOptions& co) {
  Viewer v(s, o, co);
  return v.run();
}

}  // namespace haze::view
