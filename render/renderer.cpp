#include "render/renderer.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>

namespace haze::render {

const std::vector<std::string> kAccumulationLayers = {"acc_l",    "acc_l2",    "acc_vol",   "acc_vol2",
                                                      "acc_surf", "acc_surf2", "acc_demod", "acc_demod2",
                                                      "acc_vp",   "acc_emit"};
const std::vector<std::string> kResolvedLayers = {"out_l",     "out_vol",      "out_surf", "out_var",
                                                  "out_demod", "out_demod_m2", "out_emit"};
const std::vector<std::string> kGBufferLayers = {"g_depth", "g_normal", "g_albedo"};
const std::vector<std::string> kPrevGBufferLayers = {"prev_g_depth", "prev_g_normal", "prev_g_albedo"};

namespace {

// The host offsets of the GLSL headers and the layer lists above describe the same layers.
static_assert(glsl::ACC_STRIDE == 4 * 10 && glsl::ACC_VP_WT == 4 * 8 && glsl::ACC_EMIT == 4 * 9);
static_assert(glsl::OUT_STRIDE == 4 * 7 && glsl::OUT_VPDEPTH == 4 * 1 + 3 && glsl::OUT_DEMOD == 4 * 4 &&
              glsl::OUT_EMIT == 4 * 6);
static_assert(glsl::G_STRIDE == 4 * 3 && glsl::G_MOTION == 4 * 1 + 2);

// Where a layer's float `offset` (OUT_*, G_*) lives: the layer's index.
uint32_t layer_of(uint32_t offset) {
  return offset / 4;
}

}  // namespace

FrameCounters frame_counters(const std::vector<uint32_t>& words) {
  auto at = [&](uint32_t c) { return uint64_t(words.at(2 * c)) | (uint64_t(words.at(2 * c + 1)) << 32); };
  FrameCounters f;
  f.non_finite = at(glsl::COUNT_NON_FINITE);
  f.step_cap = at(glsl::COUNT_STEP_CAP);
  f.majorant = at(glsl::COUNT_MAJORANT);
  f.clamped_squares = at(glsl::COUNT_CLAMPED_SQUARES);
  f.lookups = at(glsl::COUNT_LOOKUPS);
  f.delta_real = at(glsl::COUNT_DELTA_REAL);
  f.delta_null = at(glsl::COUNT_DELTA_NULL);
  f.distance_samples = at(glsl::COUNT_DISTANCE);
  f.guided = at(glsl::COUNT_GUIDED);
  return f;
}

double FrameCounters::null_share() const {
  const uint64_t all = delta_real + delta_null;
  return all ? double(delta_null) / double(all) : 0.0;
}

FrameCounters& FrameCounters::operator+=(const FrameCounters& o) {
  non_finite += o.non_finite;
  step_cap += o.step_cap;
  majorant += o.majorant;
  clamped_squares += o.clamped_squares;
  lookups += o.lookups;
  delta_real += o.delta_real;
  delta_null += o.delta_null;
  distance_samples += o.distance_samples;
  guided += o.guided;
  return *this;
}

nlohmann::json FrameCounters::discarded_json() const {
  return {{"non_finite", non_finite}, {"step_cap", step_cap}, {"majorant", majorant}};
}

nlohmann::json FrameCounters::tracking_json() const {
  return {{"lookups", lookups},
          {"delta_real", delta_real},
          {"delta_null", delta_null},
          {"null_share", null_share()},
          {"distance_samples", distance_samples},
          {"guided", guided}};
}

std::vector<std::string> counter_notes(const FrameCounters& c) {
  std::vector<std::string> n;
  if (c.non_finite > 0)
    n.push_back(fmt::format(
        "{} samples had a non-finite radiance and were dropped: their pixels average their other samples "
        "(biased where such samples are not rare accidents; stats.json discarded.non_finite per frame)",
        c.non_finite));
  if (c.step_cap > 0)
    n.push_back(fmt::format(
        "{} samples had a tracking query stopped at the step cap ({} steps; its transmittance taken as 0, "
        "its walk ended): the image is biased dark there; a finer render.majorant_resolution tightens the "
        "majorant",
        c.step_cap, volume::kMaxTrackingSteps));
  if (c.majorant > 0)
    n.push_back(fmt::format(
        "{} samples met an extinction above the majorant (clamped as pbrt-v4 does): the image is biased "
        "there; please report the scene",
        c.majorant));
  if (c.clamped_squares > 0)
    n.push_back(fmt::format(
        "{} samples had a squared radiance above {:g}, clamped there so that sums of squares stay "
        "finite; variance and surface_demod_m2 are lower bounds in those pixels",
        c.clamped_squares, double(glsl::SQUARE_MAX)));
  return n;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

nlohmann::json PassStats::to_json() const {
  std::vector<double> v = ms;
  std::sort(v.begin(), v.end());
  double total = 0;
  for (double x : v) total += x;
  nlohmann::json j;
  j["count"] = v.size();
  j["total_ms"] = total;
  if (!v.empty()) {
    j["median_ms"] = median(v);
    j["min_ms"] = v.front();
    j["max_ms"] = v.back();
  }
  return j;
}

CameraBasis camera_basis(const scene::Camera& c, const scene::RenderSettings& r) {
  glm::vec3 fwd = glm::normalize(c.target - c.position);
  glm::vec3 right = glm::normalize(glm::cross(fwd, c.up));
  glm::vec3 up = glm::cross(right, fwd);
  float tan_half = std::tan(glm::radians(c.fov_y) * 0.5f);
  float aspect = float(r.width) / float(r.height);
  return {glm::vec4(c.position, 0), glm::vec4(right * tan_half * aspect, 0), glm::vec4(up * tan_half, 0),
          glm::vec4(fwd, 0)};
}

std::optional<glm::vec3> light_epipole(const scene::Scene& s) {
  const auto& l = s.lights;
  if ((l.sun ? 1 : 0) + l.points.size() + l.spots.size() != 1) return std::nullopt;
  const CameraBasis cb = camera_basis(s.camera, s.render);
  const glm::vec3 right(cb.right), up(cb.up), fwd(cb.forward);
  // The light's direction from the camera (towards the sun; its image is the sheets' vanishing point).
  const glm::vec3 v =
      l.sun ? l.sun->direction
            : (l.points.empty() ? l.spots[0].position : l.points[0].position) - s.camera.position;
  const float w = glm::dot(v, fwd);
  return glm::vec3((glm::dot(v, right) / glm::dot(right, right) + w) * 0.5f * float(s.render.width),
                   (-glm::dot(v, up) / glm::dot(up, up) + w) * 0.5f * float(s.render.height), w);
}

uint32_t tonemap_op(const std::string& name) {
  return name == "aces" ? 0u : (name == "reinhard" ? 1u : 2u);
}

TonemapPush tonemap_push(const scene::RenderSettings& r, uint32_t pixels, glm::uvec2 surface_layout,
                         glm::uvec2 volume_layout) {
  return {pixels,          surface_layout.x,      surface_layout.y,     volume_layout.x,
          volume_layout.y, std::exp2(r.exposure), tonemap_op(r.tonemap)};
}

gpu::KernelDecl tonemap_decl(uint64_t pixels, bool surface_half, bool volume_half) {
  gpu::KernelDecl d("denoise/tonemap.comp");
  d.buffer("surface", pixels * (surface_half ? 8 : 12))
      .buffer("volume", pixels * (volume_half ? 8 : 12))
      .buffer("ldr", pixels * 4)
      .push(sizeof(TonemapPush))
      .specialize({surface_half ? 1u : 0u, volume_half ? 1u : 0u});
  return d;
}

// A resolved frame's outputs, copied into host-visible buffers in the frame's own command buffer, so that
// later frames may overwrite the layers while the host reads this one.
struct Renderer::Readback {
  gpu::Buffer out, gbuffer, ldr, counters, volume_motion;
  std::vector<bool> out_present;  // out's layers in the host layout; absent ones were not copied
  gpu::Buffer surface_output, surface_moments, volume_output, volume_moments;
};

Renderer::Renderer(gpu::Context& ctx, const scene::Scene& s, uint32_t frame, const scene::Scene* prev)
    : ctx_(ctx), scene_(s), media_(ctx), surfaces_(ctx), lights_(ctx), guide_(ctx), walk_splits_(ctx) {
  ring_ = std::make_unique<gpu::FrameRing>(ctx, "renderer", 2, 64);
  ring_->on_times([this](const std::vector<gpu::TimerScope>& t) { add_pass_times(t); });
  shaders_at_start_ = ctx.shaders().stats();
  load(s, frame, prev, true);
}

Renderer::~Renderer() {
  // Its frames finish while everything they use exists; what was waiting for them is dropped (the callers'
  // callbacks may be gone: finish() or resolve() is how results are taken).
  ring_->discard();
  ring_.reset();
}

gpu::Kernel Renderer::kernel(gpu::KernelDecl decl) {
  gpu::Kernel k(ctx_, std::move(decl));
  pipeline_ms_ += k.setup_ms();
  return k;
}

void Renderer::set_scene(const scene::Scene& s, uint32_t frame, const scene::Scene* prev) {
  load(s, frame, prev, false);
}

void Renderer::load(const scene::Scene& s, uint32_t frame, const scene::Scene* prev, bool fresh) {
  const scene::Scene& p = prev ? *prev : s;
  scene_ = s;
  media_.update(s);
  surfaces_.update(s, p);
  std::vector<lights::Emitter> emitters;
  for (const auto& e : surfaces_.geometry().emitters) emitters.push_back({e.v0, e.v1, e.v2, e.radiance});
  // What the camera may see, for weighing distant lights against local ones.
  lights::Bounds bounds;
  bounds.add(s.camera.position);
  if (media_.hetero()) {
    bounds.add(media_.host().majorant.world_min);
    bounds.add(media_.host().majorant.world_max);
  }
  if (s.haze && s.haze->bounded) {
    bounds.add(s.haze->bounds_min);
    bounds.add(s.haze->bounds_max);
  }
  if (surfaces_.any() && !surfaces_.geometry().bvh.nodes.empty()) {
    bounds.add(glm::vec3(surfaces_.geometry().bvh.nodes[0].bmin_left_or_first));
    bounds.add(glm::vec3(surfaces_.geometry().bvh.nodes[0].bmax_count));
  }
  lights_.update(s.lights, emitters, bounds);
  // Guiding learns where light scatters towards the camera: it needs a medium and a light, and the default
  // estimator's distance sampling on camera rays (volpath has none).
  const bool guided = s.guiding.enabled && media_.any() && lights_.any() && s.render.estimator == "default";
  guide_.update(s.guiding, uint32_t(s.render.width), uint32_t(s.render.height), guided, fresh);
  // Several walks from the camera sample's first medium vertex share its tracking and NEE.
  walk_splits_.update(s, s.render.estimator == "default" && s.render.max_depth > 1 && media_.any(), fresh);

  // The scene block: the camera and settings here, each part's share from the part.
  glsl::GpuScene g{};
  const CameraBasis cb = camera_basis(s.camera, s.render), pb = camera_basis(p.camera, s.render);
  g.cam_position = cb.position;
  g.cam_right = cb.right;
  g.cam_up = cb.up;
  g.cam_forward = cb.forward;
  g.prev_cam_position = pb.position;
  g.prev_cam_right = pb.right;
  g.prev_cam_up = pb.up;
  g.prev_cam_forward = pb.forward;
  g.size = glm::uvec4(s.render.width, s.render.height, s.render.volume_samples, s.render.max_depth);
  g.counts.w = s.render.seed ^ (frame * 0x9e3779b9u);
  g.settings = glm::vec4(s.render.equiangular_probability, s.render.rr_threshold,
                         s.render.pixel_jitter ? 1.f : 0.f, 0);
  g.sun_walk = glm::vec4(s.render.sun_walk_probability, s.render.sun_walk_g, 0, 0);
  media_.fill(g);
  lights_.fill(g);
  surfaces_.fill(g);
  guide_.fill(g);
  if (!scene_buf_.valid()) scene_buf_ = gpu::Buffer(ctx_, "scene", "scene data", sizeof(g), "GpuScene");
  if (!counters_.valid())
    counters_ =
        gpu::Buffer(ctx_, "frame counters", "per-frame temporaries", glsl::COUNTERS * 8, "u64 COUNT_*");
  scene_buf_.upload(&g, sizeof(g));
  block_ = g;
  block_dirty_ = false;
  object_motion_ = false;
  for (size_t i = 0; i < s.media.size() && i < p.media.size(); ++i)
    object_motion_ |= s.media[i].transform.matrix() != p.media[i].transform.matrix();
  for (size_t i = 0; i < s.surfaces.size() && i < p.surfaces.size(); ++i)
    object_motion_ |= s.surfaces[i].transform.matrix() != p.surfaces[i].transform.matrix();

  // The frame's layers, remade only when the size changes or emitters come or go: the camera hits' emission
  // (acc_emit, out_emit) is a layer of its own only in scenes with emissive surfaces.
  const uint64_t pixels = uint64_t(s.render.width) * s.render.height;
  const bool emission = !surfaces_.geometry().emitters.empty();
  if (accum_.pixels() != pixels || accum_.has("acc_emit") != emission) {
    accum_ = gpu::PixelLayers(ctx_, "accumulation", "per-frame temporaries", pixels, kAccumulationLayers,
                              emission ? std::vector<std::string>{} : std::vector<std::string>{"acc_emit"});
    out_ = gpu::PixelLayers(ctx_, "resolved", "outputs", pixels, kResolvedLayers,
                            emission ? std::vector<std::string>{} : std::vector<std::string>{"out_emit"});
    gbuffer_ = gpu::PixelLayers(ctx_, "g-buffer", "per-frame temporaries", pixels, kGBufferLayers);
    prev_gbuffer_ =
        gpu::PixelLayers(ctx_, "previous g-buffer", "previous-frame data", pixels, kPrevGBufferLayers);
    ldr_ = gpu::Buffer(ctx_, "preview", "outputs", pixels * 4, "RGBA8");
    has_frame_ = false;  // the resolved layers keep the last frame's virtual point depth for volume motion
  }
  accum_.fill_zero();
  clear_accum_ = false;
  samples_ = 0;
  folded_.clear();
  folded_samples_ = 0;

  // The kernels of exactly this scene's features.
  gpu::KernelDecl t("volume/trace.comp");
  t.buffer("scene", sizeof(g));
  accum_.declare(t);
  t.buffer("counters", glsl::COUNTERS * 8);
  media_.declare(t);
  lights_.declare(t);
  if (s.render.max_depth > 1) t.define("HAZE_MULTI");
  if (s.render.estimator == "volpath") {
    t.define("HAZE_VOLPATH");
  } else {
    media_.declare_default_tracking(t);
    // pbrt's walk samples the phase function alone; the default's mixes in a lobe towards the sun.
    if (s.render.max_depth > 1 && s.lights.sun && media_.any() && s.render.sun_walk_probability > 0.f)
      t.define("HAZE_SUN_WALK");
    walk_splits_.declare(t);
  }
  // Walk rays (more than one event) reach the environment and emissive triangles, which NEE samples too.
  if (s.render.mis == "power" && s.render.max_depth > 1 && (lights_.has_environment() || lights_.has_area()))
    t.define("HAZE_MIS");
  surfaces_.declare(t);
  guide_.declare(t);
  trace_ = kernel(std::move(t.push(8)));
  gpu::KernelDecl r("volume/resolve.comp");
  accum_.declare(r);
  out_.declare(r);
  resolve_ = kernel(std::move(r.buffer("ldr", pixels * 4).push(16)));
  gpu::KernelDecl gb("surfaces/gbuffer.comp");
  gb.buffer("scene", sizeof(g));
  gbuffer_.declare(gb);
  surfaces_.declare(gb);
  gbuffer_pass_ = kernel(std::move(gb));

  // The surface instance on the demodulated surface signal; the volume instance on the volume signal with
  // albedo 1 and the volume motion vectors. Each keeps its history across frames of the same size.
  keep_svgf(svgf_surface_, "surface", surfaces_.any() && s.denoise.surface.enabled, s.denoise.surface, true);
  if (svgf_surface_) svgf_surface_->set_emission(emission);
  // The epipolar term needs the scene's one light; with none or several it is off (stats: denoise_notes).
  denoise::SvgfParams volume = s.denoise.volume;
  if (!light_epipole(s)) volume.epipolar = 0;
  keep_svgf(svgf_volume_, "volume", media_.any() && s.denoise.volume.enabled, volume, false);
  if (svgf_surface_ || svgf_volume_)
    tonemap_ = kernel(tonemap_decl(pixels, bool(svgf_surface_), bool(svgf_volume_)));
  const bool virtual_points = svgf_volume_ && s.denoise.volume_motion != "surface";
  if (virtual_points || (guide_.active() && s.guiding.temporal)) {
    if (!volume_motion_ || volume_motion_->width() != uint32_t(s.render.width) ||
        volume_motion_->height() != uint32_t(s.render.height)) {
      volume_motion_.reset();
      volume_motion_ = std::make_unique<guiding::VolumeMotion>(ctx_, s.render.width, s.render.height);
      pipeline_ms_ += volume_motion_->pipeline_ms();
    }
  } else {
    volume_motion_.reset();
  }
  // How the media moved, for the pass; velocity grids only when a previous frame's points will be projected.
  media_.update_motion(s, p, bool(volume_motion_), !fresh && has_frame_);
  // Velocity moves the volume's points between frames whatever the camera does: no camera-only fast path.
  object_motion_ |= media_.velocity_grids() != nullptr;
}

void Renderer::set_camera(const scene::Camera& camera, const scene::Camera& prev, uint32_t frame) {
  if (object_motion_) {
    // The media and surface motion of the last load would still apply: reload without it.
    scene::Scene s = scene_, p = scene_;
    s.camera = camera;
    p.camera = prev;
    load(s, frame, &p, false);
    return;
  }
  scene_.camera = camera;
  const CameraBasis cb = camera_basis(camera, scene_.render), pb = camera_basis(prev, scene_.render);
  block_.cam_position = cb.position;
  block_.cam_right = cb.right;
  block_.cam_up = cb.up;
  block_.cam_forward = cb.forward;
  block_.prev_cam_position = pb.position;
  block_.prev_cam_right = pb.right;
  block_.prev_cam_up = pb.up;
  block_.prev_cam_forward = pb.forward;
  block_.counts.w = scene_.render.seed ^ (frame * 0x9e3779b9u);
  block_dirty_ = true;
  clear_accum_ = true;
  samples_ = 0;
  folded_.clear();
  folded_samples_ = 0;
}

void Renderer::restart(const scene::Scene& s, uint32_t frame, const scene::Scene* prev) {
  ring_->finish();  // the last run's times and images arrive before its statistics are cleared
  svgf_surface_.reset();
  svgf_volume_.reset();
  has_frame_ = false;
  passes_.clear();
  pipeline_ms_ = 0;
  shaders_at_start_ = ctx_.shaders().stats();
  load(s, frame, prev, true);
}

void Renderer::keep_svgf(std::unique_ptr<denoise::Svgf>& svgf, const char* name, bool wanted,
                         const denoise::SvgfParams& params, bool remodulate) {
  const auto& r = scene_.render;
  if (!wanted) {
    svgf.reset();
  } else if (svgf && svgf->width() == uint32_t(r.width) && svgf->height() == uint32_t(r.height)) {
    svgf->set_params(params);
  } else {
    svgf.reset();
    svgf = std::make_unique<denoise::Svgf>(ctx_, name, params, r.width, r.height, remodulate);
    pipeline_ms_ += svgf->pipeline_ms();
  }
}

nlohmann::json Renderer::walk_splits_stats() const {
  ring_->finish();
  return walk_splits_.stats();
}

bool Renderer::has_feature(std::string_view name) const {
  return trace_.decl().defined("HAZE_" + std::string(name));
}

gpu::Bindings Renderer::frame_bindings() const {
  gpu::Bindings b;
  b.set("scene", scene_buf_).set("ldr", ldr_).set("counters", counters_);
  accum_.bind(b);
  out_.bind(b);
  gbuffer_.bind(b);
  media_.bind(b);
  lights_.bind(b);
  surfaces_.bind(b);
  guide_.bind(b);
  walk_splits_.bind(b);
  return b;
}

void Renderer::add_pass_times(const std::vector<gpu::TimerScope>& scopes) const {
  for (const auto& t : scopes) passes_[t.pass].ms.push_back(t.end_ms - t.begin_ms);
}

const std::map<std::string, PassStats>& Renderer::pass_stats() const {
  ring_->finish();
  return passes_;
}

void Renderer::finish() {
  ring_->finish();
}

void Renderer::discard() {
  ring_->discard();
}

bool Renderer::ready() const {
  for (const gpu::Kernel* k : {&trace_, &resolve_, &gbuffer_pass_})
    if (!k->valid()) return false;
  return true;
}

void Renderer::update_block(VkCommandBuffer cmd) {
  if (!block_dirty_) return;
  vkCmdUpdateBuffer(cmd, scene_buf_.handle(), 0, sizeof(block_), &block_);
  gpu::compute_barrier(cmd);
  block_dirty_ = false;
}

void Renderer::start_frame(VkCommandBuffer cmd, gpu::Timer* timer) {
  const auto& r = scene_.render;
  if (clear_accum_) {
    accum_.fill_zero(cmd);
    clear_accum_ = false;
  }
  counters_.fill_zero(cmd);
  // Keep the last frame's G-buffer, then write this one's.
  gbuffer_.copy_to(cmd, prev_gbuffer_);
  gpu::compute_barrier(cmd);
  if (timer) timer->begin(cmd, "gbuffer");
  const auto [gx, gy] = gbuffer_pass_.groups_2d(uint32_t(r.width), uint32_t(r.height));
  gbuffer_pass_.dispatch(cmd, frame_bindings(), nullptr, gx, gy);
  if (timer) timer->end(cmd);
  gpu::compute_barrier(cmd);
  if (volume_motion_) {
    // The resolved layers still hold the previous frame's; without one, no point is projected.
    if (!has_frame_) out_.fill_zero(cmd);
    guiding::VolumeMotionInputs in;
    in.scene = &scene_buf_;
    in.prev_depth = &out_[layer_of(glsl::OUT_VPDEPTH)];
    in.depth_stride = 4;
    in.depth_offset = glsl::OUT_VPDEPTH % 4;
    if (svgf_volume_ && svgf_volume_->geometry_depth()) {
      // The volume instance's own geometry: the virtual point depth it accumulated over its history, far less
      // noisy than the last frame's alone.
      in.prev_depth = svgf_volume_->geometry_depth();
      in.depth_stride = 2;
      in.depth_offset = 0;
    }
    in.g_normal = &gbuffer_[layer_of(glsl::G_MOTION)];
    in.media = media_.motion();
    in.media_count = media_.moving();
    in.velocity_grids = media_.velocity_grids();
    volume_motion_->run(cmd, timer, in);
  }
  guide_.start_frame(cmd, timer, scene_buf_, volume_motion_ ? &volume_motion_->output() : nullptr,
                     has_frame_);
}

void Renderer::record_samples(VkCommandBuffer cmd, gpu::Timer* timer, int n) {
  const auto& r = scene_.render;
  const auto [gx, gy] = trace_.groups_2d(uint32_t(r.width), uint32_t(r.height));
  const gpu::Bindings b = frame_bindings();
  update_block(cmd);
  for (int i = 0; i < n; ++i) {
    const uint32_t push[2] = {uint32_t(samples_), walk_splits_.index()};
    if (samples_ == 0) start_frame(cmd, timer);
    // A sample adds to the sums the one before it wrote (in the same command buffer).
    if (i > 0 && !guide_.active()) gpu::compute_barrier(cmd);
    if (timer) timer->begin(cmd, "trace");
    trace_.dispatch(cmd, b, push, gx, gy);
    // The next sample reads the states this one wrote (histogram: folded after the dispatch).
    if (guide_.active()) gpu::compute_barrier(cmd);
    guide_.after_sample(cmd, scene_buf_);
    walk_splits_.after_sample(cmd);
    if (timer) timer->end(cmd);
    ++samples_;
  }
}

void Renderer::add_samples(int n, const std::function<void(int, int)>& progress) {
  for (int i = 0; i < n; ++i) {
    VkCommandBuffer cmd = ring_->begin();
    record_samples(cmd, &ring_->timer(), 1);
    if (progress) ring_->on_complete([progress, i, n] { progress(i + 1, n); });
    ring_->submit();
    if (samples_ - folded_samples_ >= kFoldSamples) fold();
  }
}

void Renderer::record_resolve(VkCommandBuffer cmd, gpu::Timer* timer) {
  const auto& r = scene_.render;
  uint32_t pixels = uint32_t(r.width) * uint32_t(r.height);
  // The preview composites the denoised signals (or the noisy one where an instance does not run).
  const gpu::Buffer& surf = out_[layer_of(glsl::OUT_SURF)];
  const gpu::Buffer& vol = out_[layer_of(glsl::OUT_VOL)];
  const TonemapPush tp =
      tonemap_push(r, pixels, glm::uvec2(4, glsl::OUT_SURF % 4), glm::uvec2(4, glsl::OUT_VOL % 4));
  struct {
    uint32_t pixels, samples;
    float exposure_scale;
    uint32_t tonemap;
  } push{pixels, uint32_t(samples_), tp.exposure_scale, tp.tonemap};
  update_block(cmd);
  if (timer) timer->begin(cmd, "resolve");
  resolve_.dispatch_1d(cmd, frame_bindings(), &push, pixels);
  if (timer) timer->end(cmd);
  if (!svgf_surface_ && !svgf_volume_) {
    has_frame_ = true;
    return;
  }
  gpu::compute_barrier(cmd);
  denoise::SvgfInputs in;
  in.gbuffer = &gbuffer_;
  in.prev_gbuffer = &prev_gbuffer_;
  in.motion = &gbuffer_[layer_of(glsl::G_MOTION)];
  in.motion_stride = 4;
  in.motion_offset = glsl::G_MOTION % 4;
  in.colour_stride = 4;
  if (svgf_surface_) {
    in.colour = &out_[layer_of(glsl::OUT_DEMOD)];
    in.colour_offset = glsl::OUT_DEMOD % 4;
    if (out_.has("out_emit")) {
      in.emission = &out_[layer_of(glsl::OUT_EMIT)];  // added back after remodulation
      in.emission_stride = 4;
      in.emission_offset = glsl::OUT_EMIT % 4;
    }
    svgf_surface_->run(cmd, timer, in);
  }
  if (svgf_volume_) {
    in.emission = nullptr;
    in.colour = &vol;
    in.colour_offset = glsl::OUT_VOL % 4;
    if (scene_.denoise.volume_motion == "backward") {
      // The baseline: this frame's own virtual points, reprojected with the camera's motion.
      guiding::VolumeMotionInputs vm;
      vm.scene = &scene_buf_;
      vm.prev_depth = &vol;
      vm.depth_stride = 4;
      vm.depth_offset = glsl::OUT_VPDEPTH % 4;
      vm.g_normal = &gbuffer_[layer_of(glsl::G_MOTION)];
      volume_motion_->run_backward(cmd, timer, vm);
    }
    if (scene_.denoise.volume_motion != "surface") {
      in.motion = &volume_motion_->output();
      in.motion_stride = 4;
      in.motion_offset = 0;
    }
    in.depth = &vol;  // used by geometry "virtual_points"
    in.depth_stride = 4;
    in.depth_offset = glsl::OUT_VPDEPTH % 4;
    in.epipole = light_epipole(scene_);  // this frame's camera
    svgf_volume_->run(cmd, timer, in);
  }
  if (timer) timer->begin(cmd, "tonemap");
  gpu::Bindings b;
  b.set("surface", svgf_surface_ ? svgf_surface_->output() : surf);
  b.set("volume", svgf_volume_ ? svgf_volume_->output() : vol);
  b.set("ldr", ldr_);
  tonemap_.dispatch_1d(cmd, b, &tp, pixels);
  if (timer) timer->end(cmd);
  has_frame_ = true;
}

std::unique_ptr<Renderer::Readback> Renderer::take_readback() {
  if (readbacks_.empty()) return std::make_unique<Readback>();
  std::unique_ptr<Readback> rb = std::move(readbacks_.back());
  readbacks_.pop_back();
  return rb;
}

void Renderer::record_readback(VkCommandBuffer cmd, Readback& rb) {
  // A readback buffer holds its source's bytes (layers one after another); remade when the size changes.
  auto copy = [&](gpu::Buffer& dst, const char* name, const std::vector<const gpu::Buffer*>& src) {
    uint64_t bytes = 0;
    for (const gpu::Buffer* b : src) bytes += b->size();
    if (bytes == 0) {
      dst = gpu::Buffer();
      return;
    }
    if (!dst.valid() || dst.size() != bytes)
      dst = gpu::Buffer::host_visible(ctx_, fmt::format("readback {}", name), "readback", bytes);
    uint64_t at = 0;
    for (const gpu::Buffer* b : src) {
      gpu::copy_buffer(cmd, *b, dst, b->size(), 0, at);
      at += b->size();
    }
  };
  auto layers = [](const gpu::PixelLayers& l) {
    std::vector<const gpu::Buffer*> v;
    for (size_t i = 0; i < l.count(); ++i)
      if (l[i].valid()) v.push_back(&l[i]);
    return v;
  };
  auto one = [](const gpu::Buffer* b) {
    return b ? std::vector<const gpu::Buffer*>{b} : std::vector<const gpu::Buffer*>{};
  };
  gpu::compute_barrier(cmd);
  rb.out_present.assign(out_.count(), false);
  for (size_t i = 0; i < out_.count(); ++i) rb.out_present[i] = out_[i].valid();
  copy(rb.out, "resolved", layers(out_));
  copy(rb.gbuffer, "g-buffer", layers(gbuffer_));
  copy(rb.ldr, "preview", one(&ldr_));
  copy(rb.counters, "frame counters", one(&counters_));
  copy(rb.volume_motion, "volume motion", one(volume_motion_ ? &volume_motion_->output() : nullptr));
  copy(rb.surface_output, "svgf.surface output", one(svgf_surface_ ? &svgf_surface_->output() : nullptr));
  copy(rb.surface_moments, "svgf.surface moments", one(svgf_surface_ ? &svgf_surface_->moments() : nullptr));
  copy(rb.volume_output, "svgf.volume output", one(svgf_volume_ ? &svgf_volume_->output() : nullptr));
  copy(rb.volume_moments, "svgf.volume moments", one(svgf_volume_ ? &svgf_volume_->moments() : nullptr));
}

Image Renderer::read_image(const Readback& rb, int samples, int width, int height) {
  const size_t pixels = size_t(width) * size_t(height);
  auto floats = [](const gpu::Buffer& b) {
    std::vector<float> v(b.size() / 4);
    b.read_mapped(v.data(), v.size() * 4);
    return v;
  };
  // Present layers one after another -> side by side (stride 4 * layers floats per pixel); absent layers
  // keep their place as zeros.
  auto interleave = [&](const gpu::Buffer& b, std::vector<bool> present) {
    const std::vector<float> planes = floats(b);
    if (present.empty()) present.assign(planes.size() / (pixels * 4), true);
    const size_t layers = present.size();
    std::vector<float> out(pixels * 4 * layers, 0.f);
    for (size_t l = 0, at = 0; l < layers; ++l) {
      if (!present[l]) continue;
      for (size_t p = 0; p < pixels; ++p)
        for (size_t c = 0; c < 4; ++c) out[(p * layers + l) * 4 + c] = planes[(at * pixels + p) * 4 + c];
      ++at;
    }
    return out;
  };
  Image img;
  img.width = width;
  img.height = height;
  img.samples = samples;
  img.data = interleave(rb.out, rb.out_present);
  img.surface_emission = rb.out_present[layer_of(glsl::OUT_EMIT)];
  img.gbuffer = interleave(rb.gbuffer, {});
  img.ldr.resize(pixels);
  rb.ldr.read_mapped(img.ldr.data(), pixels * 4);
  auto svgf = [&](const gpu::Buffer& output, const gpu::Buffer& moments) {
    std::vector<glm::uvec2> o(pixels);
    output.read_mapped(o.data(), pixels * 8);
    return denoise::Svgf::decode(pixels, o, floats(moments));
  };
  if (rb.surface_output.valid()) img.surface_denoised = svgf(rb.surface_output, rb.surface_moments);
  if (rb.volume_output.valid()) img.volume_denoised = svgf(rb.volume_output, rb.volume_moments);
  if (rb.volume_motion.valid()) {
    img.volume_motion.resize(pixels);
    rb.volume_motion.read_mapped(img.volume_motion.data(), pixels * 16);
  }
  std::vector<uint32_t> words(2 * glsl::COUNTERS);
  rb.counters.read_mapped(words.data(), words.size() * 4);
  img.counters = frame_counters(words);
  return img;
}

void Renderer::resolve_async(std::function<void(Image)> done) {
  // After a fold the resolve reads the double sums, rounded to float once.
  const bool folded = folded_samples_ > 0;
  if (folded) {
    fold();
    accum_.upload(std::vector<float>(folded_.begin(), folded_.end()));
  }
  VkCommandBuffer cmd = ring_->begin();
  record_resolve(cmd, &ring_->timer());
  if (folded) {
    // The device held the folded sums for this resolve only: the next samples add to zero again.
    gpu::compute_barrier(cmd);
    accum_.fill_zero(cmd);
  }
  std::shared_ptr<Readback> rb = take_readback();
  record_readback(cmd, *rb);
  // The scene may change before the frame is finished: its size is taken now.
  ring_->on_complete([this, rb, done = std::move(done), samples = samples_, w = scene_.render.width,
                      h = scene_.render.height, epipole = light_epipole(scene_)]() mutable {
    Image img = read_image(*rb, samples, w, h);
    img.epipole = epipole;
    readbacks_.push_back(std::make_unique<Readback>(std::move(*rb)));
    done(std::move(img));
  });
  ring_->submit();
}

std::function<Image()> Renderer::record_image(VkCommandBuffer cmd) {
  std::shared_ptr<Readback> rb = take_readback();
  record_readback(cmd, *rb);
  return [this, rb, samples = samples_, w = scene_.render.width, h = scene_.render.height,
          epipole = light_epipole(scene_)]() {
    Image img = read_image(*rb, samples, w, h);
    img.epipole = epipole;
    readbacks_.push_back(std::make_unique<Readback>(std::move(*rb)));
    return img;
  };
}

Image Renderer::resolve() {
  Image img;
  resolve_async([&img](Image i) { img = std::move(i); });
  ring_->finish();
  return img;
}

std::vector<double> Renderer::accum() const {
  ring_->finish();
  const std::vector<float> device = accum_.download();
  std::vector<double> sums(device.begin(), device.end());
  for (size_t i = 0; i < folded_.size(); ++i) sums[i] += folded_[i];
  return sums;
}

void Renderer::fold() {
  ring_->finish();
  const std::vector<float> device = accum_.download();
  folded_.resize(device.size(), 0.0);
  for (size_t i = 0; i < device.size(); ++i) folded_[i] += device[i];
  folded_samples_ = samples_;
  accum_.fill_zero();
}

std::vector<std::string> Renderer::notes() const {
  std::vector<std::string> n = media_.notes();
  const auto& g = surfaces_.geometry().notes;
  n.insert(n.end(), g.begin(), g.end());
  const auto l = lights_.notes();
  n.insert(n.end(), l.begin(), l.end());
  return n;
}

nlohmann::json Renderer::stats() const {
  ring_->finish();
  nlohmann::json j;
  j["device"] = ctx_.describe();
  // The trace kernel's features, lower case: "haze+sun", "empty" for none.
  std::string features;
  for (const auto& [name, value] : trace_.decl().defines()) {
    std::string f = name.rfind("HAZE_", 0) == 0 ? name.substr(5) : name;
    std::transform(f.begin(), f.end(), f.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    features += (features.empty() ? "" : "+") + f;
  }
  j["features"] = features.empty() ? "empty" : features;
  nlohmann::json kernels = nlohmann::json::array();
  for (const gpu::Kernel* k : {&trace_, &resolve_, &gbuffer_pass_, &tonemap_})
    if (k->valid()) kernels.push_back(k->decl().describe());
  j["kernels"] = kernels;
  const gpu::ShaderCacheStats now = ctx_.shaders().stats();
  j["shaders"] = {{"compiled", now.compiled - shaders_at_start_.compiled},
                  {"cache_hits", now.cache_hits - shaders_at_start_.cache_hits},
                  {"compile_ms", now.compile_ms - shaders_at_start_.compile_ms}};
  j["samples"] = samples_;
  j["pipeline_creation_ms"] = pipeline_ms_;
  nlohmann::json p = nlohmann::json::object();
  for (const auto& [name, st] : passes_) p[name] = st.to_json();
  j["passes"] = p;
  j["memory"] = ctx_.ledger().to_json();
  // Frames in flight: host waits for the device (frame pacing in the ring; a host access to memory a frame
  // in flight might use, Context::wait_in_flight).
  j["frame_loop"] = {{"frames_in_flight", ring_->frames()},
                     {"submissions", ring_->submitted()},
                     {"host_wait_ms", ring_->wait_ms()},
                     {"host_waits_for_memory", ctx_.host_waits()}};
  j["notes"] = notes();
  const auto& maj = media_.host().majorant;
  j["majorant_resolution"] = {maj.res.x, maj.res.y, maj.res.z};
  if (walk_splits_.learned()) j["walk_splits"] = walk_splits_.stats();
  // The volume instance's epipolar term runs only with the scene's one sun, point or spot light.
  if (svgf_volume_) j["volume_denoise"] = {{"epipolar_term", svgf_volume_->epipolar_on()}};
  return j;
}

}  // namespace haze::render
