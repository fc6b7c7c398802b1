// The haze command line: parsing and wiring only.
#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>

#include "bench/bench.hpp"
#include "eval/compare.hpp"
#include "eval/reference.hpp"
#include "eval/report.hpp"
#include "eval/sweep.hpp"
#include "gpu/gpu.hpp"
#include "lights/environment.hpp"
#include "render/denoise_sequence.hpp"
#include "render/output.hpp"
#include "render/renderer.hpp"
#include "render/run.hpp"
#include "scene/animation.hpp"
#include "scene/scene.hpp"
#include "vdb/vdb.h"
#include "view/viewer.hpp"

namespace {

using namespace haze;

// A progress bar with the elapsed time and an ETA, on stderr when it is a terminal.
struct Progress {
  const char* unit = "spp";
  bool tty = isatty(fileno(stderr));
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  // "[#####.....] 3/8 runs  12.0s  ETA 20.0s". apart_s: time within the elapsed that is not the items'
  // (a sweep's references): the ETA leaves it out and the line shows it on its own.
  std::string line(size_t done, size_t total, double apart_s = 0) const {
    double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    double eta = done > 0 ? std::max(0.0, el - apart_s) / double(done) * double(total - done) : 0;
    size_t w = 30, filled = total > 0 ? w * done / total : w;
    return fmt::format(
        "[{}{}] {}/{} {}  {:.1f}s  ETA {:.1f}s{}", std::string(filled, '#'), std::string(w - filled, '.'),
        done, total, unit, el, eta,
        apart_s > 0 ? fmt::format(" (+ references: {:.1f}s so far, not in the ETA)", apart_s) : "");
  }
  void operator()(int done, int total) const {
    if (!tty) return;
    fmt::print(stderr, "\r{} ", line(size_t(done), size_t(total)));
    if (done == total) fmt::print(stderr, "\n");
  }
};

gpu::ContextOptions context_options(const std::string& device, bool validation, const std::string& cache,
                                    const std::string& shader_cache) {
  gpu::ContextOptions o;
  o.device = device;
  o.validation = validation;
  o.pipeline_cache = cache;
  o.shader_cache = shader_cache;  // "" = $HAZE_SHADER_CACHE, else the XDG cache folder
  if (const char* e = std::getenv("HAZE_PIPELINE_CACHE"); o.pipeline_cache.empty() && e) o.pipeline_cache = e;
  return o;
}

// The scene with the command's overrides, --size and --frames applied. --frames goes through the scene's own
// render.frames so that sequence files are checked for exactly these.
scene::Scene load_scene(const std::string& path, std::vector<std::string> overrides, const std::string& size,
                        const std::string& frames) {
  if (!size.empty()) {
    int w = 0, h = 0;
    char x = 0;
    if (std::sscanf(size.c_str(), "%d%c%d", &w, &x, &h) != 3 || (x != 'x' && x != 'X'))
      throw std::runtime_error(fmt::format("--size {}: expected WIDTHxHEIGHT, e.g. 320x180", size));
    overrides.push_back(fmt::format("render.width={}", w));
    overrides.push_back(fmt::format("render.height={}", h));
  }
  if (!frames.empty()) {
    scene::parse_frames(frames);
    overrides.push_back(fmt::format("render.frames={}", frames));
  }
  return scene::load(path, overrides);
}

int run_render(const std::string& scene_path, const std::string& out, const std::string& spp,
               const std::string& size, const std::string& frames, const std::vector<std::string>& sets,
               const gpu::ContextOptions& co) {
  std::vector<std::string> overrides = sets;
  // Read as the scene file reads it (1e3 is 1000), with its range check and message.
  if (!spp.empty()) overrides.push_back(fmt::format("render.spp={}", spp));
  scene::Scene s = load_scene(scene_path, overrides, size, frames);
  auto [first, last] = scene::frame_range(s);
  // All or nothing: the frames and stats.json replace the folder's earlier ones only when every frame
  // rendered and wrote.
  render::OutputSet outs(out);
  auto frame_name = [](int f, const char* ext) { return fmt::format("frame_{:04d}.{}", f, ext); };
  for (int f = first; f <= last; ++f)
    for (const char* ext : {"exr", "png"})
      if (s.render.wants(ext)) outs.check(frame_name(f, ext));
  if (s.render.wants("stats")) outs.check("stats.json");
  render::check_part_specs(s);
  gpu::Context ctx(co);
  fmt::print(stderr, "device: {} ({})\n", ctx.device_name(), ctx.driver_info());
  render::FrameLoop loop;
  loop.progress = Progress{};
  loop.on_note = [](const std::string& n) { fmt::print(stderr, "note: {}\n", n); };
  loop.on_frame_start = [](int f, int a, int b) {
    if (b > a) fmt::print(stderr, "frame {} ({}..{})\n", f, a, b);
  };
  loop.on_frame = [&](int f, const render::Image& img) {
    if (s.render.wants("exr")) render::write_exr(outs.stage(frame_name(f, "exr")), img);
    if (s.render.wants("png")) render::write_png(outs.stage(frame_name(f, "png")), img);
  };
  std::unique_ptr<render::Renderer> r;
  render::RunSummary run = render::render_frames(ctx, s, first, last, loop, r);
  nlohmann::json st = run.stats;
  st["scene"] = scene::to_json(s);
  st["scene_file"] = scene_path;
  st["frames"] = run.per_frame;
  st["notes"] = run.notes;  // of every frame, each once
  st["setup_s"] = run.setup_s;
  st["render_s"] = run.render_s;
  if (s.render.wants("stats")) render::write_json(outs.stage("stats.json"), st);
  outs.commit();
  fmt::print(stderr, "wrote {} ({} frame{}, {} spp, {:.1f} s setup, {:.1f} s render)\n{}", out,
             last - first + 1, last > first ? "s" : "", s.render.spp, run.setup_s, run.render_s,
             render::format_summary(render::summary_of_stats(st)));
  if (ctx.validation_messages() > 0) {
    fmt::print(stderr, "haze: {} Vulkan validation messages\n", ctx.validation_messages());
    return 3;
  }
  return 0;
}

int run_reference(const std::string& scene_path, const std::string& out, const std::string& frames,
                  const std::string& size, const std::vector<std::string>& sets,
                  const eval::ReferenceOptions& o, const gpu::ContextOptions& co) {
  if (o.min_spp > o.max_spp)
    throw std::runtime_error(
        fmt::format("--min-spp {} is above --max-spp {}; lower it", o.min_spp, o.max_spp));
  scene::Scene s = load_scene(scene_path, sets, size, frames);
  auto [first, last] = scene::frame_range(s);
  render::ensure_writable_dir(out);
  render::check_part_specs(s);
  gpu::Context ctx(co);
  fmt::print(stderr, "device: {} ({})\n", ctx.device_name(), ctx.driver_info());
  eval::ReferenceHooks hooks;
  hooks.on_check = [&](const eval::ReferenceFrame& f) {
    fmt::print(stderr, "frame {}: {} spp, error {:.4g} at quantile {} (max {:.4g}), target {}\n", f.frame,
               f.spp, f.error_quantile, o.quantile, f.error_max, o.target);
  };
  hooks.on_frame = [&](const eval::ReferenceFrame& f, bool cached) {
    if (cached)
      fmt::print(stderr, "frame {}: up to date ({} spp)\n", f.frame, f.spp);
    else if (!f.converged)
      fmt::print(stderr, "note: {}\n", eval::not_converged_note(f, o));
  };
  std::unique_ptr<render::Renderer> r;
  nlohmann::json info = eval::make_reference(ctx, s, first, last, out, o, hooks, r);
  fmt::print(stderr, "wrote {} (key {})\n", out, info["key"].get<std::string>());
  return ctx.validation_messages() > 0 ? 3 : 0;
}

int run_sweep(const std::string& file, const std::string& out, const std::string& shard_text, bool merge,
              bool list, const std::vector<std::string>& sets, const gpu::ContextOptions& co) {
  eval::SweepSpec spec = eval::load_sweep(file, sets);
  eval::Shard shard = shard_text.empty() ? eval::Shard{} : eval::parse_shard(shard_text);
  if (merge) {
    nlohmann::json m = eval::merge_sweep(spec, out);
    fmt::print(stderr, "merged {} runs from {} folders into {}/results.jsonl and results.csv\n",
               m["merged"].get<size_t>(), m["sources"].get<size_t>(), out);
    return 0;
  }
  if (list) {
    std::vector<eval::Run> runs = eval::expand(spec);
    eval::check_runs(spec, runs);
    for (const auto& r : eval::shard_runs(runs, shard))
      fmt::print("{}\n", nlohmann::json{{"index", r.index}, {"run", r.id}, {"settings", r.settings}}.dump());
    return 0;
  }
  gpu::Context ctx(co);
  fmt::print(stderr, "device: {} ({})\n", ctx.device_name(), ctx.driver_info());
  const Progress bar{"runs"};
  eval::SweepHooks hooks;
  hooks.log = [&](const std::string& line) { fmt::print(stderr, "{}{}\n", bar.tty ? "\r\033[K" : "", line); };
  hooks.progress = [&](size_t done, size_t total, const nlohmann::json* row, double reference_s) {
    std::string last;
    if (row) {
      last = fmt::format("run {} {:.3g} ms/frame", (*row)["index"].get<size_t>(),
                         (*row)["time"]["gpu_ms_per_frame"].get<double>());
      if (row->contains("metrics") && (*row)["metrics"].contains("relmse"))
        last += fmt::format(" relMSE {:.3g}", (*row)["metrics"]["relmse"].get<double>());
    }
    if (bar.tty)
      fmt::print(stderr, "\r\033[K{}  {}{}", bar.line(done, total, reference_s), last,
                 done == total ? "\n" : "");
    else if (row)
      fmt::print(stderr, "{}  {}\n", bar.line(done, total, reference_s), last);
  };
  int code = eval::run_sweep(ctx, spec, out, shard, hooks);
  fmt::print(stderr, "wrote {}/results.jsonl and results.csv\n", eval::shard_dir(out, shard));
  if (ctx.validation_messages() > 0) {
    fmt::print(stderr, "haze: {} Vulkan validation messages\n", ctx.validation_messages());
    return 3;
  }
  if (code == 4)
    fmt::print(stderr, "haze: error: some runs produced NaN or Inf (see nonfinite in results.csv)\n");
  return code;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"haze: a volumetric research renderer (OpenVDB media, Vulkan compute)"};
  app.require_subcommand(0, 1);
  app.fallthrough();  // global options (--device, --shader-cache, ...) also after the subcommand
  std::string device;
  bool validation = false, list_devices = false;
  app.add_option("--device", device, "GPU by index or name substring (also $HAZE_DEVICE)");
  app.add_flag("--validation", validation, "enable the Vulkan validation layer (also $HAZE_VALIDATION=1)");
  app.add_flag("--list-devices", list_devices, "list Vulkan devices and exit");
  std::string pipeline_cache;
  app.add_option(
      "--pipeline-cache", pipeline_cache,
      "VkPipelineCache file to load and save (also $HAZE_PIPELINE_CACHE); speeds up start on real GPUs");
  std::string shader_cache;
  app.add_option("--shader-cache", shader_cache,
                 "folder of compiled shader permutations (also $HAZE_SHADER_CACHE; default "
                 "$XDG_CACHE_HOME/haze/shaders, else ~/.cache/haze/shaders)");

  auto* render = app.add_subcommand("render", "render a scene to EXR, PNG and stats.json");
  std::string scene_path, out_dir;
  std::string spp;
  std::string size;
  std::vector<std::string> sets;
  bool help_params = false;
  render->add_option("scene", scene_path, "scene JSON file (required unless --help-params)");
  render->add_option("--out", out_dir, "output directory (required unless --help-params)");
  render->add_flag("--help-params", help_params,
                   "list every scene key (type, default, range, meaning) and exit; needs no scene");
  render->add_option("--spp", spp, "samples per pixel (sets render.spp)");
  render->add_option("--size", size, "WIDTHxHEIGHT (overrides render.width/height)");
  render->add_option("--set", sets, "override any scene value: dotted.path=value (repeatable)");
  std::string frames;
  render->add_option("--frames", frames,
                     "frames A:B (both included) of an animated scene; default render.frames");

  auto* view = app.add_subcommand(
      "view", "a live window on a scene: camera, parameters, layers, GPU times, memory (docs/viewer.md)");
  std::string view_scene, view_size;
  std::vector<std::string> view_sets;
  haze::view::ViewOptions vo;
  view->add_option("scene", view_scene, "scene JSON file")->required();
  view->add_option("--size", view_size, "WIDTHxHEIGHT (overrides render.width/height)");
  view->add_option("--spp", vo.spp, "samples added per frame (default 1)");
  view->add_option("--set", view_sets, "override any scene value: dotted.path=value (repeatable)");
  view->add_option("--script", vo.script,
                   "JSON list of {\"frame\": k, ...} entries to apply (docs/viewer.md)");
  view->add_option("--frames", vo.frames, "exit after N frames (needed by --script and --screenshot)");
  view->add_option("--screenshot", vo.screenshot, "PNG of the window's last frame, written at exit");
  view->add_option("--stats", vo.stats, "JSON of the run: per-frame wall and GPU times, samples, compiles");
  view->add_option("--scale", vo.scale,
                   "window pixels per rendered pixel (default: as large as fits 960x720)");
  view->add_option("--layer", vo.layer, "the layer shown first (default final)");
  bool view_no_ui = false;
  view->add_flag("--no-ui", view_no_ui, "start with the panel hidden (H shows it)");

  auto* dn = app.add_subcommand(
      "denoise", "denoise an EXR sequence with the surface SVGF instance (layers: see README)");
  std::string dn_in, dn_out;
  std::vector<std::string> dn_sets;
  dn->add_option("input", dn_in, "folder of EXR frames (taken in name order)")->required();
  dn->add_option("--out", dn_out, "output directory")->required();
  dn->add_option("--set", dn_sets,
                 "denoiser and preview settings as scene paths: denoise.surface.*, render.exposure, "
                 "render.tonemap (repeatable)");

  auto* cmp = app.add_subcommand(
      "compare",
      "relMSE, SMAPE, MSE, PSNR, FLIP (LDR and HDR) of TEST against REF (two .exr files, or two folders "
      "of frames with the temporal-stability measure)");
  std::string cmp_ref, cmp_test, cmp_layer, cmp_flip_map;
  bool cmp_json = false;
  cmp->add_option("reference", cmp_ref, "reference .exr or folder of frames")->required();
  cmp->add_option("test", cmp_test, "test .exr or folder of frames")->required();
  cmp->add_option("--layer", cmp_layer, "EXR layer to compare (default: R, G, B), e.g. volume, denoised");
  cmp->add_flag("--json", cmp_json, "print JSON");
  cmp->add_option("--flip-map", cmp_flip_map,
                  "write the per-pixel FLIP maps: PATH.exr (flip_hdr.Y, flip_ldr.Y) and PATH.png (HDR-FLIP, "
                  "magma); for folders one pair per frame in the folder PATH");

  auto* ref = app.add_subcommand(
      "reference",
      "render a converged reference: until the per-pixel relative standard error is below a target");
  std::string ref_scene, ref_out, ref_frames, ref_size;
  std::vector<std::string> ref_sets;
  eval::ReferenceOptions ro;
  ref->add_option("scene", ref_scene, "scene JSON file")->required();
  ref->add_option("--out", ref_out, "output directory (frame_NNNN.exr, reference.json)")->required();
  ref->add_option("--target", ro.target, "per-pixel relative standard error to reach")
      ->check(CLI::Range(1e-6, 10.0));
  ref->add_option("--quantile", ro.quantile, "share of pixels that must reach it")
      ->check(CLI::Range(0.5, 1.0));
  ref->add_option("--min-spp", ro.min_spp, "samples before the first check")->check(CLI::Range(1, 1 << 24));
  ref->add_option("--max-spp", ro.max_spp, "sample budget per frame")->check(CLI::Range(1, 1 << 24));
  ref->add_option("--set", ref_sets, "override any scene value: dotted.path=value (repeatable)");
  ref->add_option("--frames", ref_frames, "frames A:B of an animated scene; default render.frames");
  ref->add_option("--size", ref_size, "WIDTHxHEIGHT (overrides render.width/height)");

  auto* sweep = app.add_subcommand(
      "sweep", "run a sweep file: every setting's GPU times, memory and error against a cached reference");
  std::string sw_file, sw_out, sw_shard;
  std::vector<std::string> sw_sets;
  bool sw_merge = false, sw_list = false;
  sweep->add_option("sweep", sw_file, "sweep JSON file (docs/workflow.md)")->required();
  sweep->add_option("--out", sw_out, "output directory (results.jsonl, results.csv, runs/, references/)")
      ->required();
  sweep->add_option("--shard", sw_shard,
                    "run only the runs with index % N == i, e.g. $SLURM_ARRAY_TASK_ID/N");
  sweep->add_flag("--merge", sw_merge,
                  "join the shard-*/ results in --out into results.jsonl and results.csv");
  sweep->add_flag("--list", sw_list, "print the runs (of the shard) as JSON lines and exit; renders nothing");
  sweep->add_option("--set", sw_sets, "extra fixed overrides dotted.path=value for every run (repeatable)");

  auto* report = app.add_subcommand("report", "an HTML report (and PNG figures) of a sweep's results");
  std::string rep_dir;
  eval::ReportOptions rep;
  report->add_option("dir", rep_dir, "the sweep's --out directory")->required();
  report->add_option("--out", rep.out, "HTML file (default DIR/report.html; figures in <name>_figures/)");
  report->add_option("--metric", rep.metric, "error axis: relmse, smape, mse, flip_ldr, flip_hdr");
  report->add_option("--images", rep.max_images, "image columns besides the reference")
      ->check(CLI::Range(1, 24));

  auto* stats = app.add_subcommand(
      "stats", "samples, time, the most expensive passes and memory per category of an output folder");
  std::string stats_dir;
  stats->add_option("dir", stats_dir, "a `haze render` --out folder, a sweep's --out, or its runs/<id>")
      ->required();

  auto* tm = app.add_subcommand("tonemap", "write one layer of an EXR as an RGB PNG preview");
  std::string tm_in, tm_layer, tm_out, tm_curve;
  double tm_exposure = NAN;
  tm->add_option("input", tm_in, ".exr file")->required();
  tm->add_option("--layer", tm_layer, "layer (default: R, G, B), e.g. volume, denoised, depth");
  tm->add_option("--exposure", tm_exposure,
                 "EV (default: render.exposure of the stats.json beside the EXR, else 0)");
  tm->add_option("--tonemap", tm_curve, "aces | reinhard | clamp (default: as --exposure, else aces)");
  tm->add_option("--out", tm_out, "output .png")->required();

  auto* vdbcmd = app.add_subcommand("vdb", "make and inspect .vdb files");
  vdbcmd->require_subcommand(1);
  auto* make =
      vdbcmd->add_subcommand("make", "write a procedural volume (box, sphere, cloud, height_fog, ramp)");
  std::string kind, vdb_out;
  haze::vdb::ProceduralSpec spec;
  std::vector<double> center, extent;
  make->add_option("kind", kind, "box | sphere | cloud | height_fog | ramp")->required();
  make->add_option("--out", vdb_out, "output .vdb file")->required();
  make->add_option("--voxel-size", spec.voxel_size, "voxel size in world units");
  make->add_option("--center", center, "centre x y z")->expected(3);
  make->add_option("--size", extent, "extent x y z (sphere/cloud: diameter in x)")->expected(3);
  make->add_option("--density", spec.density, "density inside / at the peak / at the base");
  make->add_option("--falloff", spec.falloff, "height_fog scale height; cloud noise amplitude");
  make->add_option("--frequency", spec.frequency, "cloud noise frequency");
  make->add_option("--seed", spec.seed, "cloud noise seed");
  make->add_option("--octaves", spec.octaves, "cloud noise octaves");
  std::string make_frames;
  std::vector<double> make_move;
  bool make_velocity = false;
  double make_fps = 24;
  make->add_option("--frames", make_frames,
                   "write a sequence, one file per frame A..B (\"A:B\"); --out then holds a run of # for the "
                   "frame number, as in smoke_####.vdb");
  make->add_option("--move", make_move,
                   "displacement per frame, world units (frame f is moved by f times it)")
      ->expected(3);
  make->add_flag(
      "--velocity", make_velocity,
      "also write the motion as a velocity: float grids vel.x, vel.y, vel.z in world units per second "
      "(--move times --fps) over the volume");
  make->add_option("--fps", make_fps, "frames per second of --velocity (the scene's render.fps)")
      ->check(CLI::Range(1e-3, 1e3));
  auto* info = vdbcmd->add_subcommand("info", "grids, types, bounds, voxel size, value range, memory");
  std::string info_file;
  bool info_json = false;
  info->add_option("file", info_file, ".vdb file")->required();
  info->add_flag("--json", info_json, "machine-readable output");

  auto* envcmd = app.add_subcommand("envmap", "make environment maps");
  envcmd->require_subcommand(1);
  auto* env_make = envcmd->add_subcommand(
      "make", "write a generated sky (blue gradient, brown ground, a sun disc) as a latitude-longitude map");
  std::string env_out;
  haze::lights::SkyParams sky;
  env_make->add_option("--out", env_out, "output .exr or .hdr file")->required();
  env_make->add_option("--width", sky.width, "pixels across (360 degrees)")->check(CLI::Range(2, 16384));
  env_make->add_option("--height", sky.height, "pixels down (180 degrees)")->check(CLI::Range(1, 8192));
  env_make->add_option("--sun-elevation", sky.sun_elevation, "degrees above the horizon")
      ->check(CLI::Range(-90.0, 90.0));
  env_make->add_option("--sun-azimuth", sky.sun_azimuth, "degrees from -z towards +x")
      ->check(CLI::Range(-360.0, 360.0));
  env_make->add_option("--sun-size", sky.sun_size, "angular diameter of the sun disc, degrees")
      ->check(CLI::Range(0.0, 90.0));
  env_make->add_option("--sun-radiance", sky.sun_radiance, "radiance of the sun disc")
      ->check(CLI::Range(0.0, 1e9));

  auto* bench = app.add_subcommand(
      "bench", "the benchmark suite: ratios measured in one run on one device (docs/benchmarks.md)");
  haze::bench::Options bo;
  bench->add_flag("--json", bo.json, "print JSON instead of a table");
  bench->add_option("--only", bo.only,
                    "run only these parts, comma-separated: first_frame, passes, bvh, svgf, guiding, "
                    "velocity, volume_repr, view, shafts, efficiency");
  bench->add_option("--size", bo.size, "image size WIDTHxHEIGHT");
  bench->add_option("--spp", bo.spp, "samples per measurement");
  bench->add_option("--denoise-sizes", bo.denoise_sizes, "sizes of the SVGF timings, WxH[,WxH...]");
  bench->add_option("--guiding-size", bo.guiding_size,
                    "image size of the guiding and volume denoiser figures");
  bench
      ->add_option("--guiding-seeds", bo.guiding_seeds,
                   "seeds of the guided/unguided comparison (0: skip it)")
      ->check(CLI::Range(0, 1000));
  bench
      ->add_option("--efficiency-seeds", bo.efficiency_seeds,
                   "renders per estimator of the efficiency comparison (0: skip it)")
      ->check(CLI::Range(0, 1000));
  bench
      ->add_option("--efficiency-scale", bo.efficiency_scale,
                   "image sizes and sample counts of the efficiency cases, times this")
      ->check(CLI::Range(0.05, 16.0));
  bench->add_option("--efficiency-cases", bo.efficiency_cases,
                    "efficiency cases, comma-separated: dense_cloud, haze_shaft, point_in_box, env_cloud, "
                    "sheets (default: all)");
  bench->add_option("--efficiency-set", bo.efficiency_set,
                    "JSON object merged into side a of every efficiency case (the default estimator, or the "
                    "guided side), e.g. '{\"render\": {\"rr_threshold\": 0.2}}'");
  bench->add_option("--shafts-size", bo.shafts_size, "image size of the shaft sequence (WIDTHxHEIGHT)");
  bench->add_option("--shafts-frames", bo.shafts_frames, "frames of the shaft sequence")
      ->check(CLI::Range(1, 10000));
  bench
      ->add_option("--shafts-reference-spp", bo.shafts_reference_spp,
                   "samples per reference frame of the shaft sequence")
      ->check(CLI::Range(1, 1 << 20));
  bench->add_option("--reference-dir", bo.reference_dir,
                    "cache of the shaft sequence's references (default $XDG_CACHE_HOME/haze/references)");
  bench->add_option("--shafts-set", bo.shafts_set,
                    "JSON object merged into the shaft sequence's scene, e.g. '{\"denoise\": {\"volume\": "
                    "{\"iterations\": 3}}}'");
  bench->add_option("--images", bo.images_dir,
                    "write PNGs of the shaft sequence's frames 0, 4 and the last here");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }

  try {
    gpu::ContextOptions co = context_options(device, validation, pipeline_cache, shader_cache);
    if (list_devices) {
      for (const auto& d : gpu::list_devices()) fmt::print("{}\n", d.dump());
      return 0;
    }
    if (*render && help_params) {
      fmt::print("{}", scene::format_params(scene::describe()));
      return 0;
    }
    if (*render) {
      if (scene_path.empty() || out_dir.empty())
        throw std::runtime_error(
            "haze render needs a scene file and --out DIR (or --help-params to list the keys)");
      return run_render(scene_path, out_dir, spp, size, frames, sets, co);
    }
    if (*make) {
      if (center.size() == 3) spec.center = {center[0], center[1], center[2]};
      if (extent.size() == 3) spec.size = {extent[0], extent[1], extent[2]};
      // The JSON route validates kinds and ranges exactly as a scene's procedural block does.
      nlohmann::json j = {{"kind", kind},
                          {"voxel_size", spec.voxel_size},
                          {"center", {spec.center.x, spec.center.y, spec.center.z}},
                          {"size", {spec.size.x, spec.size.y, spec.size.z}},
                          {"density", spec.density},
                          {"falloff", spec.falloff},
                          {"frequency", spec.frequency},
                          {"seed", spec.seed},
                          {"octaves", spec.octaves}};
      spec = haze::vdb::procedural_from_json(j, "haze vdb make");
      // One file, or one per frame of --frames: the same voxels, moved by f * --move through the grid's
      // transform, with the velocity that moves them.
      auto [first, last] = make_frames.empty() ? std::pair{0, 0} : scene::parse_frames(make_frames);
      if (make_frames.empty() == scene::is_sequence(vdb_out))
        throw std::runtime_error(
            make_frames.empty()
                ? fmt::format("--out {}: a run of # is a frame number; give --frames A:B for a sequence",
                              vdb_out)
                : fmt::format(
                      "--out {}: a sequence needs a run of # for the frame number, as in smoke_####.vdb",
                      vdb_out));
      const glm::dvec3 move =
          make_move.size() == 3 ? glm::dvec3(make_move[0], make_move[1], make_move[2]) : glm::dvec3(0);
      std::vector<haze::vdb::ProceduralFile> files;
      for (int f = first; f <= last; ++f) files.push_back({scene::frame_file(vdb_out, f), move * double(f)});
      haze::vdb::write_procedural(spec, files,
                                  make_velocity ? std::optional<glm::dvec3>(move * make_fps) : std::nullopt);
      if (first == last)
        fmt::print("wrote {}\n", scene::frame_file(vdb_out, first));
      else
        fmt::print("wrote {} files {} .. {}\n", last - first + 1, scene::frame_file(vdb_out, first),
                   scene::frame_file(vdb_out, last));
      return 0;
    }
    if (*env_make) {
      haze::lights::write_environment_map(env_out, haze::lights::make_sky(sky));
      fmt::print("wrote {} ({}x{})\n", env_out, sky.width, sky.height);
      return 0;
    }
    if (*info) {
      auto grids = haze::vdb::inspect(info_file);
      if (info_json) {
        fmt::print("{}\n", haze::vdb::to_json(grids).dump(2));
      } else {
        for (const auto& g : grids)
          fmt::print(
              "{:<12} {:<6} {:<10} bbox [{},{},{}]..[{},{},{}] voxel {:.4g} active {} range [{:.4g}, {:.4g}] "
              "{:.1f} MB\n",
              g.name, g.type, g.grid_class, g.index_min.x, g.index_min.y, g.index_min.z, g.index_max.x,
              g.index_max.y, g.index_max.z, g.voxel_size.x, g.active_voxels, g.value_min, g.value_max,
              g.memory_bytes / 1e6);
      }
      return 0;
    }
    if (*view) {
      if (!vo.screenshot.empty() && vo.frames == 0)
        throw std::runtime_error("--screenshot needs --frames N: the screenshot is the last of N frames");
      vo.ui = !view_no_ui;
      scene::Scene s = load_scene(view_scene, view_sets, view_size, "");
      // The viewer shows one frame: an animated scene at its first.
      s = scene::scene_at_frame(s, scene::frame_range(s).first);
      render::check_part_specs(s);
      haze::view::ViewRun r = haze::view::run_view(s, vo, co);
      if (r.validation_messages > 0) {
        fmt::print(stderr, "haze: {} Vulkan validation messages\n", r.validation_messages);
        return 3;
      }
      return 0;
    }
    if (*ref) return run_reference(ref_scene, ref_out, ref_frames, ref_size, ref_sets, ro, co);
    if (*sweep) return run_sweep(sw_file, sw_out, sw_shard, sw_merge, sw_list, sw_sets, co);
    if (*report) {
      fmt::print("wrote {}\n", eval::write_report(rep_dir, rep));
      return 0;
    }
    if (*bench) return haze::bench::run(bo, co);
    if (*stats) {
      fmt::print("{}", eval::stats_text(stats_dir));
      return 0;
    }
    if (*tm) {
      fmt::print("{}", eval::tonemap_exr(tm_in, tm_layer, tm_exposure, tm_curve, tm_out));
      return 0;
    }
    if (*cmp) {
      nlohmann::json j = eval::compare_paths(cmp_ref, cmp_test, cmp_layer, cmp_flip_map);
      fmt::print("{}", cmp_json ? j.dump(2) + "\n" : eval::format_comparison(j));
      return 0;
    }
    if (*dn) {
      nlohmann::json j = nlohmann::json::object();
      for (const auto& a : dn_sets) scene::apply_override(j, a, "--set");
      scene::Scene settings = scene::from_json(j, "--set", "");
      gpu::Context ctx(co);
      nlohmann::json st = render::denoise_sequence(ctx, dn_in, dn_out, settings);
      for (const auto& n : st["notes"]) fmt::print(stderr, "note: {}\n", n.get<std::string>());
      fmt::print(stderr, "wrote {} ({} frames)\n", dn_out, st["frames"].size());
      return ctx.validation_messages() > 0 ? 3 : 0;
    }
    fmt::print("{}", app.help());
    return 0;
  } catch (const std::exception& e) {
    fmt::print(stderr, "haze: error: {}\n", e.what());
    return 1;
  }
}
