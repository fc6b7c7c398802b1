#include "render/denoise_sequence.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>

#include "denoise/svgf.hpp"
#include "render/output.hpp"
#include "render/renderer.hpp"
#include "shaders/glsl.hpp"

namespace haze::render {

namespace fs = std::filesystem;

namespace {

const char* const kNeeds =
    "haze denoise needs surface_demod (or R/G/B), albedo, normal, depth and motion layers";

// One frame's inputs in the layouts the denoiser reads.
struct FrameInputs {
  std::vector<float> colour;         // 3 floats per pixel, demodulated
  std::vector<float> gbuffer;        // G_STRIDE floats per pixel
  std::vector<float> volume;         // 3 floats per pixel
  std::vector<float> volume_motion;  // 2 floats per pixel (volume_motion.X/Y), or empty
  std::vector<float> emission;       // surface_emission.R/G/B (kept out of surface_demod), or empty
  std::vector<float> vp_depth;       // virtual_point_depth.Z, or empty
};

class Layers {
 public:
  Layers(const ExrImage& img, std::string file) : img_(img), file_(std::move(file)) {}
  bool has(const std::string& name) const {
    return std::find(img_.channels.begin(), img_.channels.end(), name) != img_.channels.end();
  }
  const std::vector<float>& need(const std::string& name) const {
    if (!has(name)) throw Error(fmt::format("{}: no channel '{}'; {}", file_, name, kNeeds));
    return img_.channel(name);
  }
  // A G-buffer channel: must be finite.
  const std::vector<float>& finite(const std::string& name) const {
    const std::vector<float>& v = need(name);
    for (size_t p = 0; p < v.size(); ++p)
      if (!std::isfinite(v[p]))
        throw Error(fmt::format("{}: {} is not finite at pixel ({}, {}); the G-buffer layers must be finite",
                                file_, name, p % img_.width, p / img_.width));
    return v;
  }

 private:
  const ExrImage& img_;
  std::string file_;
};

bool has_layer(const ExrImage& img, const char* name) {
  return std::find(img.channels.begin(), img.channels.end(), name) != img.channels.end();
}

bool has_volume(const ExrImage& img) {
  return has_layer(img, "volume.R") && has_layer(img, "volume.G") && has_layer(img, "volume.B");
}

// Whether a sequence has a volume signal to denoise (the renderer's test is "the scene has a medium"): the
// first frame has volume_motion.X/Y (haze writes it only where its volume instance ran) or a non-zero
// volume layer.
bool volume_signal(const ExrImage& img) {
  if (!has_volume(img)) return false;
  if (has_layer(img, "volume_motion.X") && has_layer(img, "volume_motion.Y")) return true;
  for (const char* c : {"volume.R", "volume.G", "volume.B"})
    for (float v : img.channel(c))
      if (v != 0) return true;
  return false;
}

FrameInputs frame_inputs(const ExrImage& img, const std::string& file) {
  using namespace glsl;
  Layers L(img, file);
  const int W = img.width, H = img.height;
  const size_t pixels = size_t(W) * H;
  FrameInputs f;
  f.gbuffer.assign(pixels * G_STRIDE, 0.f);
  const auto& depth = L.finite("depth.Z");
  const auto *nx = &L.finite("normal.X"), *ny = &L.finite("normal.Y"), *nz = &L.finite("normal.Z");
  const auto *ar = &L.finite("albedo.R"), *ag = &L.finite("albedo.G"), *ab = &L.finite("albedo.B");
  const auto *mx = &L.finite("motion.X"), *my = &L.finite("motion.Y");
  const bool grad = L.has("depth_gradient.X") && L.has("depth_gradient.Y");
  const std::vector<float>* gx = grad ? &L.finite("depth_gradient.X") : nullptr;
  const std::vector<float>* gy = grad ? &L.finite("depth_gradient.Y") : nullptr;
  const std::vector<float>* id = L.has("instance.ID") ? &L.finite("instance.ID") : nullptr;
  const std::vector<float>* zp = L.has("depth_prev.Z") ? &L.finite("depth_prev.Z") : nullptr;
  for (size_t p = 0; p < pixels; ++p) {
    float* g = &f.gbuffer[p * G_STRIDE];
    const int x = int(p % W), y = int(p / W);
    g[G_DEPTH] = depth[p];
    if (grad) {
      g[G_DDEPTH] = (*gx)[p];
      g[G_DDEPTH + 1] = (*gy)[p];
    } else if (depth[p] > 0) {
      auto diff = [&](size_t q) { return depth[q] > 0 ? depth[q] - depth[p] : 0.f; };
      g[G_DDEPTH] = x + 1 < W ? diff(p + 1) : 0.f;
      g[G_DDEPTH + 1] = y + 1 < H ? diff(p + W) : 0.f;
    }
    vec3 n((*nx)[p], (*ny)[p], (*nz)[p]);
    n = length(n) > 0 ? normalize(n) : vec3(0, 0, 1);
    vec2 e = oct_encode(n);
    g[G_NORMAL] = e.x;
    g[G_NORMAL + 1] = e.y;
    g[G_ALBEDO] = (*ar)[p];
    g[G_ALBEDO + 1] = (*ag)[p];
    g[G_ALBEDO + 2] = (*ab)[p];
    uint32_t inst = depth[p] > 0 ? 0u : 0xffffffffu;
    if (id) inst = (*id)[p] < 0 ? 0xffffffffu : uint32_t((*id)[p]);
    g[G_INSTANCE] = uintBitsToFloat(inst);
    g[G_MOTION] = (*mx)[p];
    g[G_MOTION + 1] = (*my)[p];
    g[G_PREV_DEPTH] = zp ? (*zp)[p] : depth[p];
  }
  f.colour.resize(pixels * 3);
  const bool demod = L.has("surface_demod.R") && L.has("surface_demod.G") && L.has("surface_demod.B");
  const char* rgb[3] = {"R", "G", "B"};
  for (int c = 0; c < 3; ++c) {
    const auto& v = L.need(demod ? fmt::format("surface_demod.{}", rgb[c]) : std::string(rgb[c]));
    const auto& a = L.need(fmt::format("albedo.{}", rgb[c]));
    for (size_t p = 0; p < pixels; ++p) {
      // The same divisor as the renderer's demodulation (DEMOD_MIN_ALBEDO, 1 where no surface).
      float div = depth[p] > 0 ? std::max(a[p], DEMOD_MIN_ALBEDO) : 1.f;
      f.colour[p * 3 + c] = demod ? v[p] : v[p] / div;
    }
  }
  if (demod && L.has("surface_emission.R") && L.has("surface_emission.G") && L.has("surface_emission.B")) {
    f.emission.resize(pixels * 3);
    for (int c = 0; c < 3; ++c) {
      const auto& v = img.channel(fmt::format("surface_emission.{}", rgb[c]));
      for (size_t p = 0; p < pixels; ++p) f.emission[p * 3 + c] = v[p];
    }
  }
  f.volume.assign(pixels * 3, 0.f);
  if (has_volume(img))
    for (int c = 0; c < 3; ++c) {
      const auto& v = img.channel(fmt::format("volume.{}", rgb[c]));
      for (size_t p = 0; p < pixels; ++p) f.volume[p * 3 + c] = v[p];
    }
  if (L.has("virtual_point_depth.Z")) f.vp_depth = img.channel("virtual_point_depth.Z");
  if (L.has("volume_motion.X") && L.has("volume_motion.Y")) {
    const auto *vx = &L.finite("volume_motion.X"), *vy = &L.finite("volume_motion.Y");
    f.volume_motion.resize(pixels * 2);
    for (size_t p = 0; p < pixels; ++p) {
      f.volume_motion[p * 2] = (*vx)[p];
      f.volume_motion[p * 2 + 1] = (*vy)[p];
    }
  }
  return f;
}

}  // namespace

nlohmann::json denoise_sequence(gpu::Context& ctx, const std::string& in_dir, const std::string& out_dir,
                                const scene::Scene& settings) {
  std::error_code ec;
  if (!fs::is_directory(in_dir, ec))
    throw Error(fmt::format("{}: not a directory; pass the folder of a haze render --out or other EXR frames",
                            in_dir));
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(in_dir))
    if (e.is_regular_file() && e.path().extension() == ".exr") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  if (files.empty())
    throw Error(
        fmt::format("{}: no .exr files; haze denoise reads a sequence of multi-layer EXR frames", in_dir));
  if (fs::equivalent(in_dir, out_dir, ec))
    throw Error(
        fmt::format("--out {} is the input folder; choose another so that no frame is overwritten", out_dir));
  // All or nothing: a corrupt frame further on leaves the folder's earlier outputs as they were.
  OutputSet outs(out_dir);
  for (const auto& f : files)
    for (const char* ext : {".exr", ".png"}) outs.check(f.stem().string() + ext);
  outs.check("stats.json");

  std::unique_ptr<denoise::Svgf> svgf, svgf_volume;
  gpu::Buffer colour, emission, volume, volume_motion, vp_depth, ldr;
  // The volume instance runs where the first frame has a volume signal; it reprojects with the virtual
  // points' motion (volume_motion.X/Y) when the sequence has it and denoise.volume_motion asks for it.
  bool volume_motion_used = false;
  // The volume instance's epipolar term needs the light's image of each frame (EXR header haze.epipole).
  bool epipolar_used = false;
  std::vector<std::string> notes;
  gpu::PixelLayers gbuf, prev;
  gpu::Kernel tonemap;
  gpu::Timer timer(ctx);
  std::map<std::string, std::vector<double>> times;
  int W = 0, H = 0;
  nlohmann::json frames = nlohmann::json::array();
  for (size_t i = 0; i < files.size(); ++i) {
    const std::string file = files[i].string();
    ExrImage img = read_exr(file);
    if (i == 0) {
      W = img.width;
      H = img.height;
      const size_t pixels = size_t(W) * H;
      colour = gpu::Buffer(ctx, "input colour", "per-frame temporaries", pixels * 12, "3 x f32");
      volume = gpu::Buffer(ctx, "input volume", "per-frame temporaries", pixels * 12, "3 x f32");
      gbuf = gpu::PixelLayers(ctx, "g-buffer", "per-frame temporaries", pixels, kGBufferLayers);
      prev = gpu::PixelLayers(ctx, "previous g-buffer", "previous-frame data", pixels, kPrevGBufferLayers);
      const bool volume_instance = settings.denoise.volume.enabled && volume_signal(img);
      tonemap = gpu::Kernel(ctx, tonemap_decl(pixels, true, volume_instance));
      ldr = gpu::Buffer(ctx, "preview", "outputs", pixels * 4, "RGBA8");
      svgf = std::make_unique<denoise::Svgf>(ctx, "surface", settings.denoise.surface, W, H, true);
      if (volume_instance) {
        denoise::SvgfParams vp = settings.denoise.volume;
        if (vp.epipolar > 0 && !img.epipole) {
          notes.push_back(fmt::format(
              "{}: no haze.epipole in the EXR header (frames of a scene without exactly one sun, point or "
              "spot light): the volume instance runs without its epipolar term",
              file));
          vp.epipolar = 0;
        }
        svgf_volume = std::make_unique<denoise::Svgf>(ctx, "volume", vp, W, H, false);
        epipolar_used = svgf_volume->epipolar_on();
        volume_motion_used =
            settings.denoise.volume_motion != "surface" &&
            std::find(img.channels.begin(), img.channels.end(), "volume_motion.X") != img.channels.end();
        if (volume_motion_used)
          volume_motion =
              gpu::Buffer(ctx, "input volume motion", "per-frame temporaries", pixels * 8, "2 x f32");
        if (settings.denoise.volume.geometry == "virtual_points") {
          if (!has_layer(img, "virtual_point_depth.Z"))
            throw Error(
                fmt::format("{}: no virtual_point_depth.Z layer, which denoise.volume.geometry "
                            "\"virtual_points\" reads; use frames haze rendered, or --set "
                            "denoise.volume.geometry=surface",
                            file));
          vp_depth =
              gpu::Buffer(ctx, "input virtual point depth", "per-frame temporaries", pixels * 4, "f32");
        }
      }
    } else if (img.width != W || img.height != H) {
      throw Error(fmt::format("{}: {}x{} differs from the first frame's {}x{}; a sequence has one size", file,
                              img.width, img.height, W, H));
    }
    FrameInputs in = frame_inputs(img, file);
    // The emission is added back where the sequence has it (scenes with emissive surfaces), in every frame.
    if (i == 0 && !in.emission.empty()) {
      svgf->set_emission(true);
      emission =
          gpu::Buffer(ctx, "input emission", "per-frame temporaries", in.emission.size() * 4, "3 x f32");
    }
    if (svgf->emission() != !in.emission.empty())
      throw Error(
          fmt::format("{}: {} surface_emission.R/G/B layers; the first frame {}; a sequence has the same "
                      "layers in every frame",
                      file, in.emission.empty() ? "no" : "has", svgf->emission() ? "has them" : "does not"));
    if (svgf_volume && !has_volume(img))
      throw Error(
          fmt::format("{}: no volume.R/G/B layers, which the first frame has; a sequence has the same "
                      "layers in every frame",
                      file));
    if (volume_motion_used && in.volume_motion.empty())
      throw Error(
          fmt::format("{}: no volume_motion.X/Y layers, which the first frame has; a sequence has the "
                      "same layers in every frame",
                      file));
    if (img.epipole && (glm::any(glm::isnan(*img.epipole)) || glm::any(glm::isinf(*img.epipole))))
      throw Error(
          fmt::format("{}: the header attribute haze.epipole is not finite; write the light's image in "
                      "homogeneous pixel coordinates, or remove the attribute",
                      file));
    if (epipolar_used && !img.epipole)
      throw Error(
          fmt::format("{}: no haze.epipole in the EXR header, which the first frame has; a sequence "
                      "has the same header attributes in every frame",
                      file));
    colour.upload(in.colour);
    if (!in.emission.empty()) emission.upload(in.emission);
    volume.upload(in.volume);
    if (volume_motion_used) volume_motion.upload(in.volume_motion);
    if (vp_depth.valid()) {
      if (in.vp_depth.empty())
        throw Error(
            fmt::format("{}: no virtual_point_depth.Z layer, which the first frame has; a sequence has "
                        "the same layers in every frame",
                        file));
      vp_depth.upload(in.vp_depth);
    }
    gbuf.upload(in.gbuffer);
    if (i == 0) prev.upload(in.gbuffer);
    const TonemapPush tp = tonemap_push(settings.render, uint32_t(W * H), {0, 0}, {3, 0});
    ctx.submit_and_wait([&](VkCommandBuffer cmd) {
      timer.reset(cmd);
      denoise::SvgfInputs si{&colour, 3, 0, &gbuf, &prev, &gbuf[glsl::G_MOTION / 4], 4, glsl::G_MOTION % 4};
      if (!in.emission.empty()) si.emission = &emission;
      svgf->run(cmd, &timer, si);
      if (svgf_volume) {
        denoise::SvgfInputs vi = si;
        vi.colour = &volume;
        vi.emission = nullptr;
        if (vp_depth.valid()) vi.depth = &vp_depth;
        if (epipolar_used) vi.epipole = img.epipole;
        if (volume_motion_used) {
          vi.motion = &volume_motion;
          vi.motion_stride = 2;
          vi.motion_offset = 0;
        }
        svgf_volume->run(cmd, &timer, vi);
      }
      timer.begin(cmd, "tonemap");
      gpu::Bindings b;
      b.set("surface", svgf->output())
          .set("volume", svgf_volume ? svgf_volume->output() : volume)
          .set("ldr", ldr);
      tonemap.dispatch_1d(cmd, b, &tp, tp.pixels);
      timer.end(cmd);
      gpu::compute_barrier(cmd);
      gbuf.copy_to(cmd, prev);
    });
    double total = 0;
    for (auto& [pass, ms] : timer.read_ms()) {
      times[pass].push_back(ms);
      total += ms;
    }
    denoise::SvgfResult res = svgf->download();
    const size_t pixels = size_t(W) * H;
    std::optional<denoise::SvgfResult> vres;
    if (svgf_volume) vres = svgf_volume->download();
    std::vector<std::vector<float>> planes(13, std::vector<float>(pixels));
    for (size_t p = 0; p < pixels; ++p) {
      for (int c = 0; c < 3; ++c) {
        const float v = vres ? vres->colour[p][c] : in.volume[p * 3 + c];
        planes[c][p] = res.colour[p][c] + v;
        planes[3 + c][p] = res.colour[p][c];
        planes[8 + c][p] = v;
      }
      planes[6][p] = res.history[p];
      planes[7][p] = res.variance[p];
      if (vres) {
        planes[11][p] = vres->history[p];
        planes[12][p] = vres->variance[p];
      }
    }
    const std::string stem = files[i].stem().string();
    std::vector<std::pair<std::string, const std::vector<float>*>> layers = {
        {"denoised.R", &planes[0]},         {"denoised.G", &planes[1]},
        {"denoised.B", &planes[2]},         {"surface_denoised.R", &planes[3]},
        {"surface_denoised.G", &planes[4]}, {"surface_denoised.B", &planes[5]},
        {"surface_history.Y", &planes[6]},  {"surface_denoised_variance.Y", &planes[7]}};
    if (vres)
      layers.insert(layers.end(), {{"volume_denoised.R", &planes[8]},
                                   {"volume_denoised.G", &planes[9]},
                                   {"volume_denoised.B", &planes[10]},
                                   {"volume_history.Y", &planes[11]},
                                   {"volume_denoised_variance.Y", &planes[12]}});
    write_exr_channels(outs.stage(stem + ".exr"), W, H, layers, img.epipole);
    write_png_rgb8(outs.stage(stem + ".png"), W, H, ldr.download_vector<uint32_t>());
    frames.push_back({{"input", file}, {"gpu_ms", total}});
  }
  nlohmann::json passes = nlohmann::json::object();
  for (auto& [pass, ms] : times) passes[pass] = PassStats{ms}.to_json();
  nlohmann::json st = {
      {"device", ctx.describe()},
      {"input", in_dir},
      {"size", {W, H}},
      {"denoise", scene::to_json(settings)["denoise"]["surface"]},
      // The volume instance: null where it did not run, else its settings and motion.
      {"volume_denoise", svgf_volume
                             ? nlohmann::json{{"settings", scene::to_json(settings)["denoise"]["volume"]},
                                              {"motion", volume_motion_used ? "virtual_points" : "surface"},
                                              {"epipolar_term", epipolar_used}}
                             : nlohmann::json()},
      {"frames", frames},
      {"passes", passes},
      {"memory", ctx.ledger().to_json()},
      {"notes", notes}};
  write_json(outs.stage("stats.json"), st);
  outs.commit();
  return st;
}

}  // namespace haze::render
