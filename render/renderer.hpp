// The frame: builds the passes and buffers a scene needs (and no others), runs them per sample,
// resolves the accumulated sums into images, and reports timings and memory.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "denoise/svgf.hpp"
#include "gpu/gpu.hpp"
#include "guiding/volume_motion.hpp"
#include "scene/scene.hpp"
#include "surfaces/scene_geometry.hpp"
#include "volume/device_scene.hpp"
#include "volume/features.hpp"

namespace haze::render {

// Folder of the compiled SPIR-V: $HAZE_SPV_DIR, else the build tree's.
std::string spv_dir();

// Resolved image: OUT_STRIDE floats per pixel (layout in shaders/volume/gpu_scene.glsl) plus the preview.
struct Image {
  int width = 0, height = 0;
  int samples = 0;
  std::vector<float> data;
  std::vector<float> gbuffer;  // G_STRIDE floats per pixel
  std::vector<uint32_t> ldr;   // RGBA8, row 0 at the top (the denoised frame when a denoiser ran)
  std::optional<denoise::SvgfResult> surface_denoised;  // when the surface instance ran
  std::optional<denoise::SvgfResult> volume_denoised;   // when the volume instance ran
  std::vector<glm::vec4> volume_motion;  // when computed: guiding::VolumeMotion::output() per pixel
  float at(int x, int y, uint32_t channel) const {
    return data[(size_t(y) * width + x) * glsl::OUT_STRIDE + channel];
  }
  float g(int x, int y, uint32_t channel) const {
    return gbuffer[(size_t(y) * width + x) * glsl::G_STRIDE + channel];
  }
};

// Push constants of shaders/denoise/tonemap.comp: exposure 2^render.exposure and the tone curve (0 aces,
// 1 reinhard, 2 clamp) of render.tonemap. A signal given as floats is `stride` floats per pixel with its rgb
// at `offset`; its specialization constant (SURFACE_HALF, VOLUME_HALF) says whether it is an SVGF output
// instead, whose stride and offset are then unused.
struct TonemapPush {
  uint32_t pixels, surface_stride, surface_offset, volume_stride, volume_offset;
  float exposure_scale;
  uint32_t tonemap;
};
TonemapPush tonemap_push(const scene::RenderSettings& r, uint32_t pixels, glm::uvec2 surface_layout = {0, 0},
                         glm::uvec2 volume_layout = {0, 0});

// Median of a sample (the middle pair's mean for even sizes); 0 for an empty one.
double median(std::vector<double> v);

// Summary of per-pass GPU times over all submissions.
struct PassStats {
  std::vector<double> ms;
  nlohmann::json to_json() const;
};

class Renderer {
 public:
  // `prev` is the previous frame's scene (camera and transforms) for motion vectors; default: no motion.
  Renderer(gpu::Context& ctx, const scene::Scene& s, uint32_t frame = 0, const scene::Scene* prev = nullptr);
  ~Renderer();

  // Switches to another (static) scene, e.g. the next animation frame, and clears the accumulation.
  // Pipelines, buffers of unchanged size and grids of unchanged media are kept.
  void set_scene(const scene::Scene& s, uint32_t frame, const scene::Scene* prev = nullptr);
  // Starts an independent render of `s` (a sweep's next run): as set_scene, but every history (denoisers,
  // guide, virtual points), the pass statistics and the pipeline time start afresh. Pipelines are kept.
  void restart(const scene::Scene& s, uint32_t frame, const scene::Scene* prev = nullptr);

  // One dispatch per sample; progress(done, total) after each.
  void add_samples(int n, const std::function<void(int, int)>& progress = {});
  int samples() const { return samples_; }
  // Means of the samples so far, the G-buffer, and the denoisers' output: each call is one frame for them
  // (their history advances), so call it once per frame.
  Image resolve();
  // Raw per-pixel sums (ACC_STRIDE floats per pixel) for tests.
  std::vector<float> accum() const;

  const volume::Features& features() const { return features_; }
  const volume::DeviceMedia& media() const { return media_; }
  // What loading the scene changed or dropped (clamped g, dropped triangles, ...), one line each.
  std::vector<std::string> notes() const;
  const surfaces::SceneGeometry& geometry() const { return geometry_; }
  // The distance-guiding states (K vec4 {W, N, m1, m2} per grid vertex, shaders/guiding/guide.glsl); empty
  // without guiding.
  std::vector<glm::vec4> guide_states() const;
  const std::map<std::string, PassStats>& pass_stats() const { return passes_; }
  double pipeline_ms() const { return pipeline_ms_; }
  nlohmann::json stats() const;

 private:
  gpu::Context& ctx_;
  scene::Scene scene_;
  volume::Features features_;
  volume::DeviceMedia media_;
  surfaces::SceneGeometry geometry_;
  size_t num_lights_ = 0;
  gpu::Buffer scene_buf_, accum_buf_, lights_buf_, nanovdb_buf_, media_buf_, majorant_buf_;
  gpu::Buffer out_buf_, ldr_buf_;
  gpu::Buffer bvh_nodes_buf_, bvh_tris_buf_, instances_buf_;  // surfaces only
  gpu::Buffer triangle_uvs_buf_, texels_buf_;                 // albedo textures only
  gpu::Buffer gbuffer_buf_, prev_gbuffer_buf_;
  gpu::Buffer guide_buf_, guide_prev_buf_;  // guiding only
  gpu::Buffer media_motion_buf_;            // moving media only (guiding::glsl::MediumMotion each)
  uint32_t moving_media_ = 0;
  bool has_frame_ = false;  // a frame was resolved since the buffers were (re)made: history exists
  std::map<std::string, std::unique_ptr<gpu::ComputePipeline>> pipelines_;  // by SPIR-V path
  const gpu::ComputePipeline* trace_ = nullptr;
  const gpu::ComputePipeline* resolve_ = nullptr;
  const gpu::ComputePipeline* gbuffer_ = nullptr;
  const gpu::ComputePipeline* tonemap_ = nullptr;
  const gpu::ComputePipeline* guide_reproject_ = nullptr;
  std::unique_ptr<denoise::Svgf> svgf_surface_;           // scenes with surfaces, denoise.surface.enabled
  std::unique_ptr<denoise::Svgf> svgf_volume_;            // scenes with media, denoise.volume.enabled
  std::unique_ptr<guiding::VolumeMotion> volume_motion_;  // for the volume instance and guiding's reuse
  std::unique_ptr<gpu::Timer> timer_;
  std::map<std::string, PassStats> passes_;
  double pipeline_ms_ = 0;
  int samples_ = 0;

  void record_times();
  // The BVH, instance and texture buffers in the order trace.comp and gbuffer.comp bind them.
  void append_surface_buffers(std::vector<const gpu::Buffer*>& b) const;
  const gpu::ComputePipeline* pipeline(const std::string& spv, uint32_t num_buffers, uint32_t push_bytes,
                                       const std::vector<uint32_t>& spec = {});
  // Makes `svgf` exist with `params` at the scene's size when `wanted` (keeping its history when the size is
  // unchanged), else drops it.
  void keep_svgf(std::unique_ptr<denoise::Svgf>& svgf, const char* name, bool wanted,
                 const denoise::SvgfParams& params, bool remodulate);
  // Where this frame starts: the previous frame's virtual points projected forward, the guide carried over.
  void start_frame(VkCommandBuffer cmd);
  // Reallocates `b` only when its size changes.
  void ensure(gpu::Buffer& b, const char* name, const char* category, uint64_t bytes,
              const std::string& format);
};

}  // namespace haze::render
