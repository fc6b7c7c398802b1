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
  timer_ = std::make_unique<gpu::Timer>(ctx, 16);
  set_scene(s, frame, prev);
}

const gpu::ComputePipeline* Renderer::pipeline(const std::string& spv, uint32_t num_buffers,
                                               uint32_t push_bytes) {
  auto& p = pipelines_[spv];
  if (!p) {
    p = std::make_unique<gpu::ComputePipeline>(ctx_, spv, num_buffers, push_bytes);
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

  const uint32_t surface_buffers = features_.surfaces ? (features_.texture ? 5 : 3) : 0;
  uint32_t num_buffers = 2 + (features_.lights() ? 1 : 0) + (features_.hetero ? 3 : 0) + surface_buffers;
  std::string dir = spv_dir();
  trace_ = pipeline(fmt::format("{}/volume/trace.comp.{}.spv", dir, features_.mask()), num_buffers, 4);
  resolve_ = pipeline(fmt::format("{}/volume/resolve.comp.0.spv", dir), 3, 16);
  gbuffer_ = pipeline(fmt::format("{}/surfaces/gbuffer.comp.{}.spv", dir, features_.gbuffer_mask()),
                      2 + surface_buffers, 0);

  // The surface denoiser keeps its history across frames of the same size.
  if (features_.surfaces && s.denoise.surface.enabled) {
    if (!svgf_surface_ || svgf_surface_->width() != uint32_t(s.render.width) ||
        svgf_surface_->height() != uint32_t(s.render.height)) {
      svgf_surface_.reset();
      svgf_surface_ = std::make_unique<denoise::Svgf>(ctx_, "surface", s.denoise.surface, s.render.width,
                                                      s.render.height, /*remodulate=*/true, dir);
      pipeline_ms_ += svgf_surface_->pipeline_ms();
    } else {
      svgf_surface_->set_params(s.denoise.surface);
    }
    tonemap_ = pipeline(fmt::format("{}/denoise/tonemap.comp.0.spv", dir), 3, 20);
  } else {
    svgf_surface_.reset();
  }
}

TonemapPush tonemap_push(const scene::RenderSettings& r, uint32_t pixels, uint32_t volume_stride,
                         uint32_t volume_offset) {
  const uint32_t op = r.tonemap == "aces" ? 0u : (r.tonemap == "reinhard" ? 1u : 2u);
  return {pixels, volume_stride, volume_offset, std::exp2(r.exposure), op};
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

void Renderer::add_samples(int n, const std::function<void(int, int)>& progress) {
  const auto& r = scene_.render;
  uint32_t gx = (uint32_t(r.width) + 7) / 8, gy = (uint32_t(r.height) + 7) / 8;
  for (int i = 0; i < n; ++i) {
    uint32_t sample_index = uint32_t(samples_);
    ctx_.submit_and_wait([&](VkCommandBuffer cmd) {
      timer_->reset(cmd);
      if (samples_ == 0) {
        // A new frame: keep the last frame's G-buffer, then write this one's.
        gpu::copy_buffer(cmd, gbuffer_buf_, prev_gbuffer_buf_);
        gpu::compute_barrier(cmd);
        timer_->begin(cmd, "gbuffer");
        std::vector<const gpu::Buffer*> gb = {&scene_buf_, &gbuffer_buf_};
        append_surface_buffers(gb);
        gbuffer_->dispatch(cmd, gb, nullptr, gx, gy);
        timer_->end(cmd);
      }
      timer_->begin(cmd, "trace");
      std::vector<const gpu::Buffer*> b = {&scene_buf_, &accum_buf_};
      if (features_.lights()) b.push_back(&lights_buf_);
      if (features_.hetero) {
        b.push_back(&nanovdb_buf_);
        b.push_back(&media_buf_);
        b.push_back(&majorant_buf_);
      }
      append_surface_buffers(b);
      trace_->dispatch(cmd, b, &sample_index, gx, gy);
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
  // The preview of the noisy means, or (below) of the denoised frame: denoised surface + volume signal.
  const TonemapPush tp = tonemap_push(r, pixels, glsl::OUT_STRIDE, glsl::OUT_VOL);
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
    if (svgf_surface_) {
      gpu::compute_barrier(cmd);
      denoise::SvgfInputs in;
      in.colour = &out_buf_;
      in.colour_stride = glsl::OUT_STRIDE;
      in.colour_offset = glsl::OUT_DEMOD;
      in.gbuffer = &gbuffer_buf_;
      in.prev_gbuffer = &prev_gbuffer_buf_;
      in.motion = &gbuffer_buf_;
      in.motion_stride = glsl::G_STRIDE;
      in.motion_offset = glsl::G_MOTION;
      svgf_surface_->run(cmd, timer_.get(), in);
      timer_->begin(cmd, "tonemap");
      tonemap_->dispatch(cmd, {&svgf_surface_->output(), &out_buf_, &ldr_buf_}, &tp, (pixels + 63) / 64);
      timer_->end(cmd);
    }
  });
  record_times();
  Image img;
  img.width = r.width;
  img.height = r.height;
  img.samples = samples_;
  img.data = out_buf_.download_vector<float>();
  img.ldr = ldr_buf_.download_vector<uint32_t>();
  img.gbuffer = gbuffer_buf_.download_vector<float>();
  if (svgf_surface_) img.surface_denoised = svgf_surface_->download();
  return img;
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
