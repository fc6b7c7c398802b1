#include "render/renderer.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>

#ifndef HAZE_DEFAULT_SPV_DIR
#define HAZE_DEFAULT_SPV_DIR "spv"
#endif

namespace haze::render {

std::string spv_dir() {
  if (const char* e = std::getenv("HAZE_SPV_DIR"); e && *e) return e;
  return HAZE_DEFAULT_SPV_DIR;
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

Renderer::Renderer(gpu::Context& ctx, const scene::Scene& s, uint32_t frame, const scene::Scene* prev)
    : ctx_(ctx), scene_(s) {
  timer_ = std::make_unique<gpu::Timer>(ctx, 48);
  set_scene(s, frame, prev);
}

const gpu::ComputePipeline* Renderer::pipeline(const std::string& spv, uint32_t num_buffers,
                                               uint32_t push_bytes, const std::vector<uint32_t>& spec) {
  std::string key = spv;
  for (uint32_t c : spec) key += fmt::format("#{}", c);
  auto& p = pipelines_[key];
  if (!p) {
    p = std::make_unique<gpu::ComputePipeline>(ctx_, spv, num_buffers, push_bytes, spec);
    pipeline_ms_ += p->creation_ms();
  }
  return p.get();
}

void Renderer::ensure(gpu::Buffer& b, const char* name, const char* category, uint64_t bytes,
                      const std::string& format) {
  if (!b.valid() || b.size() != bytes) b = gpu::Buffer(ctx_, name, category, bytes, format);
}

void Renderer::set_scene(const scene::Scene& s, uint32_t frame, const scene::Scene* prev) {
  scene_ = s;
  features_ = volume::features_of(s);
  media_ = volume::build_media(s, &media_);
  geometry_ = surfaces::build_geometry(s, &geometry_);
  std::vector<glsl::GpuLight> lights = volume::build_lights(s);
  size_t num_local = s.lights.points.size() + s.lights.spots.size();
  // Emissive triangles go after the point and spot lights (which equi-angular sampling walks).
  std::vector<glsl::GpuLight> tri_lights;
  for (const auto& e : geometry_.emitters) {
    glsl::GpuLight l{};
    l.position = glm::vec4(e.v0, float(glsl::LIGHT_TRIANGLE));
    l.radiance = glm::vec4(e.radiance, 0);
    l.direction = glm::vec4(e.v1, 0);
    l.params = glm::vec4(e.v2, 0);
    tri_lights.push_back(l);
  }
  lights.insert(lights.begin() + num_local, tri_lights.begin(), tri_lights.end());
  num_lights_ = lights.size();
  const scene::Scene& p = prev ? *prev : s;
  glsl::GpuScene gs = volume::build_gpu_scene(s, media_, lights.size(), num_local, frame, &p.camera);
  size_t pixels = size_t(s.render.width) * s.render.height;

  ensure(scene_buf_, "scene", "scene data", sizeof(gs), "GpuScene");
  scene_buf_.upload(&gs, sizeof(gs));
  ensure(accum_buf_, "accumulation", "per-frame temporaries", pixels * glsl::ACC_STRIDE * 4,
         fmt::format("{} x f32 per pixel", glsl::ACC_STRIDE));
  accum_buf_.fill_zero();
  samples_ = 0;
  // The resolved layers keep the last frame's virtual point depth for the next frame's volume motion.
  if (!out_buf_.valid() || out_buf_.size() != pixels * glsl::OUT_STRIDE * 4) has_frame_ = false;
  ensure(out_buf_, "resolved layers", "outputs", pixels * glsl::OUT_STRIDE * 4,
         fmt::format("{} x f32 per pixel", glsl::OUT_STRIDE));
  ensure(ldr_buf_, "preview", "outputs", pixels * 4, "RGBA8");
  // Buffers exist only for the features the scene uses.
  if (features_.lights()) {
    ensure(lights_buf_, "lights", "scene data", lights.size() * sizeof(glsl::GpuLight), "GpuLight");
    lights_buf_.upload(lights);
  } else {
    lights_buf_ = gpu::Buffer();
  }
  if (features_.hetero) {
    ensure(nanovdb_buf_, "nanovdb grids", "scene data", media_.nanovdb.size() * 4, "NanoVDB");
    nanovdb_buf_.upload(media_.nanovdb);
    ensure(media_buf_, "media", "scene data", media_.media.size() * sizeof(glsl::GpuMedium), "GpuMedium");
    media_buf_.upload(media_.media);
    ensure(majorant_buf_, "majorant grid", "scene data", media_.majorant.sigma_max.size() * 4,
           fmt::format("f32 {}x{}x{}", media_.majorant.res.x, media_.majorant.res.y, media_.majorant.res.z));
    majorant_buf_.upload(media_.majorant.sigma_max);
  } else {
    nanovdb_buf_ = gpu::Buffer();
    media_buf_ = gpu::Buffer();
    majorant_buf_ = gpu::Buffer();
  }

  if (features_.surfaces) {
    const auto& bvh = geometry_.bvh;
    ensure(bvh_nodes_buf_, "bvh nodes", "scene data", bvh.nodes.size() * sizeof(glsl::GpuBvhNode),
           "GpuBvhNode");
    bvh_nodes_buf_.upload(bvh.nodes);
    ensure(bvh_tris_buf_, "bvh triangles", "scene data", bvh.triangles.size() * sizeof(glsl::GpuTriangle),
           "GpuTriangle");
    bvh_tris_buf_.upload(bvh.triangles);
    std::vector<glm::uvec4> placement;
    std::vector<glm::uvec2> texels = surfaces::packed_texels(geometry_, &placement);
    std::vector<glsl::GpuInstance> inst;
    for (size_t i = 0; i < s.surfaces.size(); ++i) {
      glsl::GpuInstance g{};
      if (geometry_.instance_texture[i] >= 0) g.texture = placement[size_t(geometry_.instance_texture[i])];
      g.albedo = glm::vec4(s.surfaces[i].albedo, 0);
      g.emission = glm::vec4(s.surfaces[i].emission, 0);
      glm::mat4 now = s.surfaces[i].transform.matrix();
      glm::mat4 before = i < p.surfaces.size() ? p.surfaces[i].transform.matrix() : now;
      g.world_to_prev_world = glm::mat4(glm::dmat4(before) * glm::inverse(glm::dmat4(now)));
      inst.push_back(g);
    }
    ensure(instances_buf_, "instances", "scene data", inst.size() * sizeof(glsl::GpuInstance), "GpuInstance");
    instances_buf_.upload(inst);
    if (features_.texture) {
      ensure(triangle_uvs_buf_, "triangle uvs", "scene data",
             geometry_.triangle_uvs.size() * sizeof(glsl::GpuTriangleUv), "GpuTriangleUv");
      triangle_uvs_buf_.upload(geometry_.triangle_uvs);
      ensure(texels_buf_, "albedo textures", "scene data", texels.size() * sizeof(glm::uvec2),
             fmt::format("RGB unorm16, {} textures", placement.size()));
      texels_buf_.upload(texels);
    } else {
      triangle_uvs_buf_ = gpu::Buffer();
      texels_buf_ = gpu::Buffer();
    }
  } else {
    bvh_nodes_buf_ = gpu::Buffer();
    bvh_tris_buf_ = gpu::Buffer();
    instances_buf_ = gpu::Buffer();
    triangle_uvs_buf_ = gpu::Buffer();
    texels_buf_ = gpu::Buffer();
  }
  ensure(gbuffer_buf_, "g-buffer", "per-frame temporaries", pixels * glsl::G_STRIDE * 4,
         fmt::format("{} x f32 per pixel", glsl::G_STRIDE));
  ensure(prev_gbuffer_buf_, "previous g-buffer", "previous-frame data", pixels * glsl::G_STRIDE * 4,
         fmt::format("{} x f32 per pixel", glsl::G_STRIDE));

  const bool media = features_.hetero || features_.haze;
  if (features_.guiding) {
    glm::uvec2 grid = volume::guide_grid_size(s);
    uint64_t bytes = uint64_t(grid.x) * grid.y * uint32_t(s.guiding.states) * 16;
    if (!guide_buf_.valid() || guide_buf_.size() != bytes) {
      const std::string format =
          fmt::format("{}x{} vertices x {} states x vec4", grid.x, grid.y, s.guiding.states);
      guide_buf_ = gpu::Buffer(ctx_, "guiding states", "guiding state", bytes, format);
      guide_prev_buf_ = gpu::Buffer(ctx_, "guiding states (previous frame)", "guiding state", bytes, format);
      guide_buf_.fill_zero();
    }
  } else {
    guide_buf_ = gpu::Buffer();
    guide_prev_buf_ = gpu::Buffer();
  }

  // How each VDB medium moved since the previous frame, for the virtual points inside it.
  std::vector<guiding::glsl::MediumMotion> moved;
  for (size_t i = 0; i < s.media.size() && i < p.media.size() && i < media_.media.size(); ++i) {
    glm::dmat4 now = s.media[i].transform.matrix(), before = p.media[i].transform.matrix();
    if (now == before) continue;
    guiding::glsl::MediumMotion m{};
    glm::dmat4 prev_to_now = now * glm::inverse(before), now_to_prev = before * glm::inverse(now);
    m.prev_world_to_world = glm::mat4(prev_to_now);
    glm::dvec3 lo(1e300), hi(-1e300);
    const glm::dvec3 a(media_.media[i].world_min), b(media_.media[i].world_max);
    for (int c = 0; c < 8; ++c) {
      glm::dvec3 corner(c & 1 ? b.x : a.x, c & 2 ? b.y : a.y, c & 4 ? b.z : a.z);
      glm::dvec3 q = glm::dvec3(now_to_prev * glm::dvec4(corner, 1));
      lo = glm::min(lo, q);
      hi = glm::max(hi, q);
    }
    m.prev_min = glm::vec4(glm::vec3(lo), 0);
    m.prev_max = glm::vec4(glm::vec3(hi), 0);
    moved.push_back(m);
  }
  moving_media_ = uint32_t(moved.size());
  if (!moved.empty()) {
    ensure(media_motion_buf_, "media motion", "scene data", moved.size() * sizeof(moved[0]), "MediumMotion");
    media_motion_buf_.upload(moved);
  } else {
    media_motion_buf_ = gpu::Buffer();
  }

  const uint32_t surface_buffers = features_.surfaces ? (features_.texture ? 5 : 3) : 0;
  uint32_t num_buffers = 2 + (features_.lights() ? 1 : 0) + (features_.hetero ? 3 : 0) + surface_buffers +
                         (features_.guiding ? 1 : 0);
  std::string dir = spv_dir();
  trace_ = pipeline(fmt::format("{}/volume/trace.comp.{}.spv", dir, features_.mask()), num_buffers, 4);
  resolve_ = pipeline(fmt::format("{}/volume/resolve.comp.0.spv", dir), 3, 16);
  gbuffer_ = pipeline(fmt::format("{}/surfaces/gbuffer.comp.{}.spv", dir, features_.gbuffer_mask()),
                      2 + surface_buffers, 0);

  // The surface denoiser keeps its history across frames of the same size.
  // The surface instance on the demodulated surface signal; the volume instance on the volume signal with
  // albedo 1 and the volume motion vectors.
  keep_svgf(svgf_surface_, "surface", features_.surfaces && s.denoise.surface.enabled, s.denoise.surface,
            true);
  keep_svgf(svgf_volume_, "volume", media && s.denoise.volume.enabled, s.denoise.volume, false);
  if (svgf_surface_ || svgf_volume_)
    tonemap_ = pipeline(fmt::format("{}/denoise/tonemap.comp.0.spv", dir), 3, sizeof(TonemapPush),
                        {svgf_surface_ ? 1u : 0u, svgf_volume_ ? 1u : 0u});
  const bool virtual_points = svgf_volume_ && s.denoise.volume_motion == "virtual_points";
  if (virtual_points || (features_.guiding && s.guiding.temporal)) {
    if (!volume_motion_ || volume_motion_->width() != uint32_t(s.render.width) ||
        volume_motion_->height() != uint32_t(s.render.height)) {
      volume_motion_.reset();
      volume_motion_ = std::make_unique<guiding::VolumeMotion>(ctx_, s.render.width, s.render.height, dir);
      pipeline_ms_ += volume_motion_->pipeline_ms();
    }
  } else {
    volume_motion_.reset();
  }
  guide_reproject_ =
      features_.guiding ? pipeline(fmt::format("{}/guiding/guide_reproject.comp.0.spv", dir), 4, 0) : nullptr;
}

void Renderer::restart(const scene::Scene& s, uint32_t frame, const scene::Scene* prev) {
  svgf_surface_.reset();
  svgf_volume_.reset();
  has_frame_ = false;
  passes_.clear();
  pipeline_ms_ = 0;
  set_scene(s, frame, prev);
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
    svgf = std::make_unique<denoise::Svgf>(ctx_, name, params, r.width, r.height, remodulate, spv_dir());
    pipeline_ms_ += svgf->pipeline_ms();
  }
}

TonemapPush tonemap_push(const scene::RenderSettings& r, uint32_t pixels, glm::uvec2 surface_layout,
                         glm::uvec2 volume_layout) {
  const uint32_t op = r.tonemap == "aces" ? 0u : (r.tonemap == "reinhard" ? 1u : 2u);
  return {pixels, surface_layout.x, surface_layout.y, volume_layout.x, volume_layout.y, std::exp2(r.exposure),
          op};
}

Renderer::~Renderer() = default;

void Renderer::append_surface_buffers(std::vector<const gpu::Buffer*>& b) const {
  if (!features_.surfaces) return;
  b.insert(b.end(), {&bvh_nodes_buf_, &bvh_tris_buf_, &instances_buf_});
  if (features_.texture) b.insert(b.end(), {&triangle_uvs_buf_, &texels_buf_});
}

void Renderer::record_times() {
  for (auto& [name, ms] : timer_->read_ms()) passes_[name].ms.push_back(ms);
}

void Renderer::start_frame(VkCommandBuffer cmd) {
  const auto& r = scene_.render;
  uint32_t gx = (uint32_t(r.width) + 7) / 8, gy = (uint32_t(r.height) + 7) / 8;
  // Keep the last frame's G-buffer, then write this one's.
  gpu::copy_buffer(cmd, gbuffer_buf_, prev_gbuffer_buf_);
  gpu::compute_barrier(cmd);
  timer_->begin(cmd, "gbuffer");
  std::vector<const gpu::Buffer*> gb = {&scene_buf_, &gbuffer_buf_};
  append_surface_buffers(gb);
  gbuffer_->dispatch(cmd, gb, nullptr, gx, gy);
  timer_->end(cmd);
  gpu::compute_barrier(cmd);
  if (volume_motion_) {
    // out_buf_ still holds the previous frame's resolve; without one, no point is projected.
    if (!has_frame_) out_buf_.fill_zero(cmd);
    guiding::VolumeMotionInputs in;
    in.scene = &scene_buf_;
    in.prev_depth = &out_buf_;
    in.depth_stride = glsl::OUT_STRIDE;
    in.depth_offset = glsl::OUT_VPDEPTH;
    in.gbuffer = &gbuffer_buf_;
    in.media = moving_media_ ? &media_motion_buf_ : nullptr;
    in.media_count = moving_media_;
    volume_motion_->run(cmd, timer_.get(), in);
  }
  if (features_.guiding) {
    if (!scene_.guiding.temporal) {
      guide_buf_.fill_zero(cmd);
    } else if (has_frame_) {
      // Each vertex takes the states of the previous frame's vertex its virtual point came from.
      std::swap(guide_buf_, guide_prev_buf_);
      timer_->begin(cmd, "guide_reproject");
      const glm::uvec2 grid = volume::guide_grid_size(scene_);
      const uint32_t states = grid.x * grid.y * uint32_t(scene_.guiding.states);
      guide_reproject_->dispatch(cmd, {&scene_buf_, &volume_motion_->output(), &guide_prev_buf_, &guide_buf_},
                                 nullptr, (states + 63) / 64);
      timer_->end(cmd);
    }
    gpu::compute_barrier(cmd);
  }
}

void Renderer::add_samples(int n, const std::function<void(int, int)>& progress) {
  const auto& r = scene_.render;
  uint32_t gx = (uint32_t(r.width) + 7) / 8, gy = (uint32_t(r.height) + 7) / 8;
  for (int i = 0; i < n; ++i) {
    uint32_t sample_index = uint32_t(samples_);
    ctx_.submit_and_wait([&](VkCommandBuffer cmd) {
      timer_->reset(cmd);
      if (samples_ == 0) start_frame(cmd);
      timer_->begin(cmd, "trace");
      std::vector<const gpu::Buffer*> b = {&scene_buf_, &accum_buf_};
      if (features_.lights()) b.push_back(&lights_buf_);
      if (features_.hetero) {
        b.push_back(&nanovdb_buf_);
        b.push_back(&media_buf_);
        b.push_back(&majorant_buf_);
      }
      append_surface_buffers(b);
      if (features_.guiding) b.push_back(&guide_buf_);
      trace_->dispatch(cmd, b, &sample_index, gx, gy);
      // The next sample reads the states this one wrote.
      if (features_.guiding) gpu::compute_barrier(cmd);
      timer_->end(cmd);
    });
    record_times();
    ++samples_;
    if (progress) progress(i + 1, n);
  }
}

Image Renderer::resolve() {
  const auto& r = scene_.render;
  uint32_t pixels = uint32_t(r.width) * uint32_t(r.height);
  // The preview composites the denoised signals (or the noisy one where an instance does not run).
  const TonemapPush tp = tonemap_push(r, pixels, glm::uvec2(glsl::OUT_STRIDE, glsl::OUT_SURF),
                                      glm::uvec2(glsl::OUT_STRIDE, glsl::OUT_VOL));
  struct {
    uint32_t pixels, samples;
    float exposure_scale;
    uint32_t tonemap;
  } push{pixels, uint32_t(samples_), tp.exposure_scale, tp.tonemap};
  ctx_.submit_and_wait([&](VkCommandBuffer cmd) {
    timer_->reset(cmd);
    timer_->begin(cmd, "resolve");
    resolve_->dispatch(cmd, {&accum_buf_, &out_buf_, &ldr_buf_}, &push, (pixels + 63) / 64);
    timer_->end(cmd);
    if (!svgf_surface_ && !svgf_volume_) return;
    gpu::compute_barrier(cmd);
    denoise::SvgfInputs in;
    in.colour = &out_buf_;
    in.colour_stride = glsl::OUT_STRIDE;
    in.gbuffer = &gbuffer_buf_;
    in.prev_gbuffer = &prev_gbuffer_buf_;
    in.motion = &gbuffer_buf_;
    in.motion_stride = glsl::G_STRIDE;
    in.motion_offset = glsl::G_MOTION;
    if (svgf_surface_) {
      in.colour_offset = glsl::OUT_DEMOD;
      svgf_surface_->run(cmd, timer_.get(), in);
    }
    if (svgf_volume_) {
      in.colour_offset = glsl::OUT_VOL;
      if (scene_.denoise.volume_motion == "virtual_points") {
        in.motion = &volume_motion_->output();
        in.motion_stride = 4;
        in.motion_offset = 0;
      }
      svgf_volume_->run(cmd, timer_.get(), in);
    }
    timer_->begin(cmd, "tonemap");
    tonemap_->dispatch(cmd,
                       {svgf_surface_ ? &svgf_surface_->output() : &out_buf_,
                        svgf_volume_ ? &svgf_volume_->output() : &out_buf_, &ldr_buf_},
                       &tp, (pixels + 63) / 64);
    timer_->end(cmd);
  });
  record_times();
  has_frame_ = true;
  Image img;
  img.width = r.width;
  img.height = r.height;
  img.samples = samples_;
  img.data = out_buf_.download_vector<float>();
  img.ldr = ldr_buf_.download_vector<uint32_t>();
  img.gbuffer = gbuffer_buf_.download_vector<float>();
  if (svgf_surface_) img.surface_denoised = svgf_surface_->download();
  if (svgf_volume_) img.volume_denoised = svgf_volume_->download();
  if (volume_motion_) img.volume_motion = volume_motion_->download();
  return img;
}

std::vector<glm::vec4> Renderer::guide_states() const {
  return guide_buf_.valid() ? guide_buf_.download_vector<glm::vec4>() : std::vector<glm::vec4>{};
}

std::vector<float> Renderer::accum() const {
  return accum_buf_.download_vector<float>();
}

std::vector<std::string> Renderer::notes() const {
  std::vector<std::string> n = media_.notes;
  n.insert(n.end(), geometry_.notes.begin(), geometry_.notes.end());
  return n;
}

nlohmann::json Renderer::stats() const {
  nlohmann::json j;
  j["device"] = ctx_.describe();
  j["features"] = features_.describe();
  j["shader_variant"] = features_.mask();
  j["samples"] = samples_;
  j["pipeline_creation_ms"] = pipeline_ms_;
  nlohmann::json p = nlohmann::json::object();
  for (const auto& [name, st] : passes_) p[name] = st.to_json();
  j["passes"] = p;
  j["memory"] = ctx_.ledger().to_json();
  j["notes"] = notes();
  j["majorant_resolution"] = {media_.majorant.res.x, media_.majorant.res.y, media_.majorant.res.z};
  return j;
}

}  // namespace haze::render
