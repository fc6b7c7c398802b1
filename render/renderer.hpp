// The frame: composes the passes a scene needs (and no others) from its parts (media, surfaces, lights,
// guiding, the denoisers), runs them per sample, resolves the accumulated sums into images, and reports
// timings and memory. The renderer owns only the frame's own data: the scene block, the accumulation,
// resolved and G-buffer layers and the preview; every part owns, reuses and binds its own buffers.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "denoise/svgf.hpp"
#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "gpu/pixel_layers.hpp"
#include "guiding/guide.hpp"
#include "guiding/volume_motion.hpp"
#include "lights/lights.hpp"
#include "render/walk_splits.hpp"
#include "scene/scene.hpp"
#include "surfaces/device_surfaces.hpp"
#include "volume/media.hpp"

namespace haze::render {

// The frame's per-pixel layers, in layer order (host offsets ACC_*, OUT_*, G_* of the GLSL headers are
// 4 * layer + component).
extern const std::vector<std::string> kAccumulationLayers;  // acc_l ... acc_vp
extern const std::vector<std::string> kResolvedLayers;      // out_l ... out_demod_m2
extern const std::vector<std::string> kGBufferLayers;       // g_depth, g_normal, g_albedo
extern const std::vector<std::string> kPrevGBufferLayers;   // prev_g_depth, prev_g_normal, prev_g_albedo

// What a frame's samples cut and what its trackers did: the COUNT_* counters of
// shaders/volume/gpu_scene.glsl, summed over the frame's samples.
struct FrameCounters {
  // Discarded: samples dropped for a non-finite radiance (not counted as samples of their pixel), samples
  // in which a tracking query stopped at the step cap, samples that met sigma_t above the majorant.
  uint64_t non_finite = 0, step_cap = 0, majorant = 0;
  uint64_t clamped_squares = 0;               // samples with a square capped at SQUARE_MAX
  uint64_t lookups = 0;                       // density lookups of the trackers
  uint64_t delta_real = 0, delta_null = 0;    // delta tracking's real and null collisions
  uint64_t distance_samples = 0, guided = 0;  // distance samples on camera rays; drawn from the guide

  uint64_t discarded() const { return non_finite + step_cap + majorant; }
  // Share of delta tracking's tentative collisions that were null (0 without any).
  double null_share() const;
  FrameCounters& operator+=(const FrameCounters& o);
  // {"non_finite", "step_cap", "majorant"}: stats.json's `discarded`.
  nlohmann::json discarded_json() const;
  // {"lookups", "delta_real", "delta_null", "null_share", "distance_samples", "guided"}: `tracking`.
  nlohmann::json tracking_json() const;
};
// The counters from the counters buffer's words (two per counter: low, high).
FrameCounters frame_counters(const std::vector<uint32_t>& words);
// `note:` lines for what a run's samples discarded or clamped (none when nothing was).
std::vector<std::string> counter_notes(const FrameCounters& c);

// Resolved image: OUT_STRIDE floats per pixel (layout in shaders/volume/gpu_scene.glsl) plus the preview.
struct Image {
  int width = 0, height = 0;
  int samples = 0;
  std::vector<float> data;
  std::vector<float> gbuffer;     // G_STRIDE floats per pixel
  bool surface_emission = false;  // the scene has emissive surfaces: OUT_EMIT holds their emission (else 0)
  std::vector<uint32_t> ldr;      // RGBA8, row 0 at the top (the denoised frame when a denoiser ran)
  std::optional<denoise::SvgfResult> surface_denoised;  // when the surface instance ran
  std::optional<denoise::SvgfResult> volume_denoised;   // when the volume instance ran
  std::vector<glm::vec4> volume_motion;  // when computed: guiding::VolumeMotion::output() per pixel
  FrameCounters counters;                // what the frame's samples discarded, clamped and tracked
  std::optional<glm::vec3> epipole;      // light_epipole() of the frame's camera (EXR header haze.epipole)
  float at(int x, int y, uint32_t channel) const {
    return data[(size_t(y) * width + x) * glsl::OUT_STRIDE + channel];
  }
  float g(int x, int y, uint32_t channel) const {
    return gbuffer[(size_t(y) * width + x) * glsl::G_STRIDE + channel];
  }
};

// The camera as the shaders use it (shaders/common/camera.glsl): right and up scaled by the field of view.
struct CameraBasis {
  glm::vec4 position, right, up, forward;
};
CameraBasis camera_basis(const scene::Camera& c, const scene::RenderSettings& r);
// The image of the scene's one sun, point or spot light in homogeneous pixel coordinates (x, y, w; pixel
// (x / w, y / w), w = 0 for a sun direction parallel to the image plane), what the volume instance's epipolar
// term needs; none when the scene has no such light or several.
std::optional<glm::vec3> light_epipole(const scene::Scene& s);

// Push constants of shaders/denoise/tonemap.comp: exposure 2^render.exposure and the tone curve (0 aces,
// 1 reinhard, 2 clamp) of render.tonemap. A signal given as floats is `stride` floats per pixel with its rgb
// at `offset`; its specialization constant (SURFACE_HALF, VOLUME_HALF) says whether it is an SVGF output
// instead, whose stride and offset are then unused.
struct TonemapPush {
  uint32_t pixels, surface_stride, surface_offset, volume_stride, volume_offset;
  float exposure_scale;
  uint32_t tonemap;
};
// render.tonemap's name as the shaders' tone-curve number (0 aces, 1 reinhard, 2 clamp).
uint32_t tonemap_op(const std::string& name);
TonemapPush tonemap_push(const scene::RenderSettings& r, uint32_t pixels, glm::uvec2 surface_layout = {0, 0},
                         glm::uvec2 volume_layout = {0, 0});
// The tonemap kernel: the surface and the volume signal as SVGF outputs (half) or floats.
gpu::KernelDecl tonemap_decl(uint64_t pixels, bool surface_half, bool volume_half);

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
  // Kernels, buffers of unchanged size and grids of unchanged media are kept.
  void set_scene(const scene::Scene& s, uint32_t frame, const scene::Scene* prev = nullptr);
  // Starts an independent render of `s` (a sweep's next run): as set_scene, but every history (denoisers,
  // guide, virtual points), the pass statistics and the kernel setup time start afresh. Kernels are kept.
  void restart(const scene::Scene& s, uint32_t frame, const scene::Scene* prev = nullptr);
  // A new camera only (a live view): as set_scene with the current scene seen from `camera` at `frame`, the
  // previous frame seen from `prev` (motion vectors), but nothing is uploaded or rebuilt: the scene block is
  // updated in the next recorded frame, so no frame in flight is waited for.
  void set_camera(const scene::Camera& camera, const scene::Camera& prev, uint32_t frame);

  // The frame loop streams: each sample is one submission of this renderer's frame ring
  // (gpu::FrameRing, two in flight), and the host waits only for the submission two before (never for
  // the one it just made). progress(done, total) as each completes.
  void add_samples(int n, const std::function<void(int, int)>& progress = {});
  int samples() const { return samples_; }
  // Means of the samples so far, the G-buffer, and the denoisers' output: each call is one frame for them
  // (their history advances), so call it once per frame. Waits for the frame.
  Image resolve();
  // As resolve(), without waiting: `done` receives the image once the frame is finished on the device (from
  // a later submission or finish()); the outputs are copied into a readback buffer of the frame's own.
  void resolve_async(std::function<void(Image)> done);
  // Waits for this renderer's submissions in flight and runs what waits for them (timings, images).
  void finish();
  // Waits for them and drops what waits for them (a failed run; also on destruction).
  void discard();
  // Raw per-pixel sums (ACC_STRIDE per pixel): the device's float sums of the samples since the last fold
  // plus the folded double sums. Waits for the samples in flight.
  std::vector<double> accum() const;
  // The device sums at most this many samples in float before they are folded into double sums on the
  // host, so that a reference of 2^24 samples still converges (a float sum stops growing once a sample is
  // below half its ulp). Renders of fewer samples never fold; add_samples folds (a wait for the device), the
  // samples a caller records itself (record_samples) do not.
  static constexpr int kFoldSamples = 1024;
  int folded_samples() const { return folded_samples_; }

  // The same passes recorded into a caller's frame (a viewer's command buffer, timed with its timer): the
  // first samples of a frame start it (G-buffer, volume motion, the guide carried over); `record_resolve`
  // resolves, denoises and tonemaps into preview(). The caller reports the frame's times with
  // add_pass_times once they are read.
  void record_samples(VkCommandBuffer cmd, gpu::Timer* timer, int n);
  void record_resolve(VkCommandBuffer cmd, gpu::Timer* timer);
  void add_pass_times(const std::vector<gpu::TimerScope>& scopes) const;
  // Copies the last resolved frame's outputs in the caller's frame; the function returned reads them as an
  // Image once that frame is finished (a viewer's "Save image").
  std::function<Image()> record_image(VkCommandBuffer cmd);
  // What a viewer shows: the 8-bit preview (RGBA8, row 0 at the top), the resolved layers, the G-buffer,
  // the denoisers, the volume motion (null where absent).
  const gpu::Buffer& preview() const { return ldr_; }
  const gpu::PixelLayers& resolved() const { return out_; }
  const gpu::PixelLayers& gbuffer() const { return gbuffer_; }
  const denoise::Svgf* surface_denoiser() const { return svgf_surface_.get(); }
  const denoise::Svgf* volume_denoiser() const { return svgf_volume_.get(); }
  const guiding::VolumeMotion* volume_motion() const { return volume_motion_.get(); }
  const guiding::Guide& guide() const { return guide_; }
  // render.walk_splits 0: the learned K* and its statistics (waits for the device); else empty.
  nlohmann::json walk_splits_stats() const;
  const scene::Scene& scene() const { return scene_; }
  // Whether every kernel of the current scene is ready (false while a deferred compile runs, gpu/kernel.hpp).
  bool ready() const;

  // The trace kernel's permutation, and whether it has feature HAZE_<name> ("GUIDING", "SURFACES", ...).
  const gpu::KernelDecl& trace_decl() const { return trace_.decl(); }
  bool has_feature(std::string_view name) const;
  const volume::DeviceMedia& media() const { return media_.host(); }
  const volume::Media& device_media() const { return media_; }
  const lights::Lights& lights() const { return lights_; }
  const gpu::Buffer& scene_buffer() const { return scene_buf_; }
  // What loading the scene changed or dropped (clamped g, dropped triangles, ...), one line each.
  std::vector<std::string> notes() const;
  const surfaces::SceneGeometry& geometry() const { return surfaces_.geometry(); }
  // The distance-guiding states (K vec4 {W, N, m1, m2} per grid vertex, or the histogram model's floats per
  // vertex, shaders/guiding/guide.glsl); empty without guiding.
  std::vector<glm::vec4> guide_states() const { return guide_.download(); }
  // The GPU times of every submission (finish() first: they arrive a frame late).
  const std::map<std::string, PassStats>& pass_stats() const;
  // Those that arrived so far, without waiting (from inside a completion such as resolve_async's).
  const std::map<std::string, PassStats>& pass_stats_so_far() const { return passes_; }
  double pipeline_ms() const { return pipeline_ms_; }  // compiling and creating this run's kernels
  nlohmann::json stats() const;

 private:
  struct Readback;  // a resolved frame's outputs copied for the host
  gpu::Context& ctx_;
  scene::Scene scene_;
  // The parts.
  volume::Media media_;
  surfaces::DeviceSurfaces surfaces_;
  lights::Lights lights_;
  guiding::Guide guide_;
  WalkSplits walk_splits_;
  std::unique_ptr<denoise::Svgf> svgf_surface_;           // scenes with surfaces, denoise.surface.enabled
  std::unique_ptr<denoise::Svgf> svgf_volume_;            // scenes with media, denoise.volume.enabled
  std::unique_ptr<guiding::VolumeMotion> volume_motion_;  // for the volume instance and guiding's reuse
  // The frame's own data.
  gpu::Buffer scene_buf_, ldr_, counters_;
  gpu::PixelLayers accum_, out_, gbuffer_, prev_gbuffer_;
  gpu::Kernel trace_, resolve_, gbuffer_pass_, tonemap_;
  bool has_frame_ = false;  // a frame was resolved since the layers were (re)made: history exists
  glsl::GpuScene block_{};  // what scene_buf_ holds (or will, once block_dirty_ is recorded)
  bool block_dirty_ = false;
  bool clear_accum_ = false;    // the accumulation is cleared at the next frame's start
  bool object_motion_ = false;  // the last load's previous frame placed media or surfaces elsewhere
  // Declared after everything its frames use, so that it is destroyed (and finished) first.
  mutable std::map<std::string, PassStats> passes_;
  std::vector<std::unique_ptr<Readback>> readbacks_;  // free ones, reused
  mutable std::unique_ptr<gpu::FrameRing> ring_;
  double pipeline_ms_ = 0;
  gpu::ShaderCacheStats shaders_at_start_;  // the context's compiler counters when this run began
  int samples_ = 0;
  std::vector<double> folded_;  // double sums of the folded samples (ACC_STRIDE per pixel), empty before
  int folded_samples_ = 0;

  // Adds the device's sums to folded_ and zeroes them.
  void fold();

  // set_scene, or with `fresh` the start of an independent run (the guide's states are emptied).
  void load(const scene::Scene& s, uint32_t frame, const scene::Scene* prev, bool fresh);
  // A kernel from the context's cache; adds its setup time to pipeline_ms_.
  gpu::Kernel kernel(gpu::KernelDecl decl);
  // Makes `svgf` exist with `params` at the scene's size when `wanted` (keeping its history when the size is
  // unchanged), else drops it.
  void keep_svgf(std::unique_ptr<denoise::Svgf>& svgf, const char* name, bool wanted,
                 const denoise::SvgfParams& params, bool remodulate);
  // Where this frame starts: the G-buffer, the previous frame's virtual points projected forward, the guide
  // carried over.
  void start_frame(VkCommandBuffer cmd, gpu::Timer* timer);
  gpu::Bindings frame_bindings() const;
  void update_block(VkCommandBuffer cmd);  // records block_ into scene_buf_ when it changed
  std::unique_ptr<Readback> take_readback();
  void record_readback(VkCommandBuffer cmd, Readback& rb);
  static Image read_image(const Readback& rb, int samples, int width, int height);
};

}  // namespace haze::render
