// `haze reference`: a converged image of a scene, rendered until the per-pixel relative standard error
// falls below a target (or a sample budget is spent), with its variance, cached under a key of everything
// that changes the converged image so that sweeps over estimator settings share one reference.
#pragma once

#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gpu/gpu.hpp"
#include "render/renderer.hpp"
#include "scene/scene.hpp"

namespace haze::eval {

struct ReferenceOptions {
  // Per pixel e = max over RGB of sqrt(var / n / (mean^2 + 0.01)): the standard error in relMSE's units,
  // so the reference's own expected relMSE is about the mean of e^2.
  double target = 0.01;
  double quantile = 0.99;  // share of pixels whose e must be <= target (1: every pixel)
  int min_spp = 64;        // the first check; the sample count doubles between checks
  int max_spp = 16384;     // budget per frame: stop there even when the target is not met
  nlohmann::json to_json() const;
};
// Reads {"target", "quantile", "min_spp", "max_spp"} (each optional); `origin` names the source in errors.
ReferenceOptions reference_options_from_json(const nlohmann::json& j, const std::string& origin);

// render.seed of every reference: sweeps must use other seeds, or a test would share its samples.
inline constexpr uint32_t kReferenceSeed = 4000000007u;

// FNV-1a 64 of `bytes` as 16 hex digits.
std::string hash_key(std::string_view bytes);

// The scene as the reference renders it: the default estimator, guiding on (its defaults; it applies where
// the scene has a medium and a light), both denoisers off, kReferenceSeed.
scene::Scene reference_scene(const scene::Scene& s);
// What the key covers: the scene without its estimator-only settings (spp, seed, volume samples, majorant
// resolution, equi-angular share, roulette threshold, estimator, outputs, preview, frames, guiding, denoise),
// the contents of every file it reads (a sequence's by name: its files are checked per frame, frame_inputs),
// and the options.
nlohmann::json reference_identity(const scene::Scene& s, const ReferenceOptions& o);
std::string reference_key(const scene::Scene& s, const ReferenceOptions& o);
// Hash of the sequence files `s` reads at `frame`: a reference frame is reused only while it matches.
std::string frame_inputs(const scene::Scene& s, int frame);

std::string reference_frame_path(const std::string& dir, int frame);  // dir/frame_0007.exr
std::string reference_png_path(const std::string& dir, int frame);    // its preview, dir/frame_0007.png

// A reference renders no denoiser, so its frames hold each denoised layer as the noisy layer it estimates
// (denoised: R, G, B; surface_denoised: surface; volume_denoised: volume), and a comparison of any of them
// reads the same layer on both sides.
inline const std::vector<std::pair<std::string, std::string>> kDenoisedStandIns = {
    {"denoised", ""}, {"surface_denoised", "surface"}, {"volume_denoised", "volume"}};

struct ReferenceFrame {
  int frame = 0, spp = 0;
  double error_quantile = 0, error_max = 0;  // e at `quantile`, and its maximum
  bool converged = false;                    // error_quantile <= target
  double seconds = 0;
  nlohmann::json to_json() const;
};

// The sample count of the next convergence check after `spp` samples reached `error`: where e ~ 1/sqrt(n)
// meets the target (10% over), more than spp and at most 4 spp, capped at max_spp.
int next_check_spp(int spp, double error, const ReferenceOptions& o);
// "reference frame F did not converge: error E at quantile Q after N spp (S s), target T; about M spp ...".
std::string not_converged_note(const ReferenceFrame& f, const ReferenceOptions& o);

struct ReferenceHooks {
  std::function<void(const ReferenceFrame&)> on_check;  // after each convergence check
  std::function<void(const ReferenceFrame&, bool cached)> on_frame;
};

// Makes (or finds) the reference of frames first..last of `s` in `dir`: frame_NNNN.exr (every layer, the
// variance among them) and reference.json (key, options, per-frame spp and error). Frames already there
// under the same key are kept; a dir holding another key is an error. Locked against concurrent makers of
// the same dir (sweep shards). `r` is reused as in render_frames.
nlohmann::json make_reference(gpu::Context& ctx, const scene::Scene& s, int first, int last,
                              const std::string& dir, const ReferenceOptions& o, const ReferenceHooks& hooks,
                              std::unique_ptr<render::Renderer>& r);

// The per-pixel errors e of a resolved image (see ReferenceOptions::target).
std::vector<float> relative_standard_errors(const render::Image& img);

}  // namespace haze::eval
