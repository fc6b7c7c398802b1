// The haze command line: parsing and wiring only.
#include <fmt/format.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>

#include "bench/bench.hpp"
#include "gpu/gpu.hpp"
#include "render/compare.hpp"
#include "render/denoise_sequence.hpp"
#include "render/output.hpp"
#include "render/renderer.hpp"
#include "scene/animation.hpp"
#include "scene/scene.hpp"
#include "vdb/vdb.h"

namespace {

using namespace haze;

struct Progress {
  bool tty = isatty(fileno(stderr));
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  void operator()(int done, int total) const {
    if (!tty) return;
    double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    double eta = done > 0 ? el / done * (total - done) : 0;
    int w = 30, filled = total > 0 ? w * done / total : w;
    fmt::print(stderr, "\r[{}{}] {}/{} spp  {:.1f}s  ETA {:.1f}s ", std::string(filled, '#'),
               std::string(w - filled, '.'), done, total, el, eta);
    if (done == total) fmt::print(stderr, "\n");
  }
};

gpu::ContextOptions context_options(const std::string& device, bool validation, const std::string& cache) {
  gpu::ContextOptions o;
  o.device = device;
  o.validation = validation;
  o.pipeline_cache = cache;
  if (const char* e = std::getenv("HAZE_PIPELINE_CACHE"); o.pipeline_cache.empty() && e) o.pipeline_cache = e;
  return o;
}

int run_render(const std::string& scene_path, const std::string& out, int spp, const std::string& size,
               const std::string& frames, const std::vector<std::string>& sets,
               const gpu::ContextOptions& co) {
  std::vector<std::string> overrides = sets;
  if (spp > 0) overrides.push_back(fmt::format("render.spp={}", spp));
  if (!size.empty()) {
    int w = 0, h = 0;
    char x = 0;
    if (std::sscanf(size.c_str(), "%d%c%d", &w, &x, &h) != 3 || (x != 'x' && x != 'X'))
      throw std::runtime_error(fmt::format("--size {}: expected WIDTHxHEIGHT, e.g. 320x180", size));
    overrides.push_back(fmt::format("render.width={}", w));
    overrides.push_back(fmt::format("render.height={}", h));
  }
  // --frames goes through the scene's own render.frames so that sequence files are checked for exactly these.
  if (!frames.empty()) {
    scene::parse_frames(frames);
    overrides.push_back(fmt::format("render.frames={}", frames));
  }
  scene::Scene s = scene::load(scene_path, overrides);
  auto [first, last] = scene::frame_range(s);
  render::ensure_writable_dir(out);
  gpu::Context ctx(co);
  fmt::print(stderr, "device: {} ({})\n", ctx.device_name(), ctx.driver_info());
  std::unique_ptr<render::Renderer> r;
  nlohmann::json per_frame = nlohmann::json::array();
  std::vector<std::string> notes;
  double setup_s = 0, render_s = 0;
  for (int f = first; f <= last; ++f) {
    auto t0 = std::chrono::steady_clock::now();
    scene::Scene fs = scene::scene_at_frame(s, f);
    scene::Scene prev = scene::scene_at_frame(s, f - 1);  // for motion vectors
    if (!r)
      r = std::make_unique<render::Renderer>(ctx, fs, uint32_t(f), &prev);
    else
      r->set_scene(fs, uint32_t(f), &prev);
    for (const auto& n : r->notes())
      if (std::find(notes.begin(), notes.end(), n) == notes.end()) {
        fmt::print(stderr, "note: {}\n", n);
        notes.push_back(n);
      }
    auto t1 = std::chrono::steady_clock::now();
    if (last > first) fmt::print(stderr, "frame {} ({}..{})\n", f, first, last);
    size_t before = r->pass_stats().count("trace") ? r->pass_stats().at("trace").ms.size() : 0;
    r->add_samples(fs.render.spp, Progress{});
    render::Image img = r->resolve();
    auto t2 = std::chrono::steady_clock::now();
    std::string base = (std::filesystem::path(out) / fmt::format("frame_{:04d}", f)).string();
    if (fs.render.wants("exr")) render::write_exr(base + ".exr", img);
    if (fs.render.wants("png")) render::write_png(base + ".png", img);
    const auto& trace = r->pass_stats().at("trace").ms;
    double trace_ms = 0;
    for (size_t i = before; i < trace.size(); ++i) trace_ms += trace[i];
    double fsetup = std::chrono::duration<double>(t1 - t0).count();
    double frender = std::chrono::duration<double>(t2 - t1).count();
    setup_s += fsetup;
    render_s += frender;
    per_frame.push_back(
        {{"frame", f}, {"setup_s", fsetup}, {"render_s", frender}, {"trace_gpu_ms", trace_ms}});
  }
  nlohmann::json st = r->stats();
  st["scene"] = scene::to_json(s);
  st["scene_file"] = scene_path;
  st["frames"] = per_frame;
  st["notes"] = notes;  // of every frame, each once
  st["setup_s"] = setup_s;
  st["render_s"] = render_s;
  if (s.render.wants("stats")) render::write_json((std::filesystem::path(out) / "stats.json").string(), st);
  fmt::print(stderr, "wrote {} ({} frame{}, {} spp, {:.1f} s setup, {:.1f} s render)\n", out,
             last - first + 1, last > first ? "s" : "", s.render.spp, setup_s, render_s);
  if (ctx.validation_messages() > 0) {
    fmt::print(stderr, "haze: {} Vulkan validation messages\n", ctx.validation_messages());
    return 3;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"haze: a volumetric research renderer (OpenVDB media, Vulkan compute)"};
  app.require_subcommand(0, 1);
  std::string device;
  bool validation = false, list_devices = false;
  app.add_option("--device", device, "GPU by index or name substring (also $HAZE_DEVICE)");
  app.add_flag("--validation", validation, "enable the Vulkan validation layer (also $HAZE_VALIDATION=1)");
  app.add_flag("--list-devices", list_devices, "list Vulkan devices and exit");
  std::string pipeline_cache;
  app.add_option(
      "--pipeline-cache", pipeline_cache,
      "VkPipelineCache file to load and save (also $HAZE_PIPELINE_CACHE); speeds up start on real GPUs");

  auto* render = app.add_subcommand("render", "render a scene to EXR, PNG and stats.json");
  std::string scene_path, out_dir;
  int spp = 0;
  std::string size;
  std::vector<std::string> sets;
  render->add_option("scene", scene_path, "scene JSON file")->required();
  render->add_option("--out", out_dir, "output directory")->required();
  render->add_option("--spp", spp, "samples per pixel (overrides render.spp)")->check(CLI::PositiveNumber);
  render->add_option("--size", size, "WIDTHxHEIGHT (overrides render.width/height)");
  render->add_option("--set", sets, "override any scene value: dotted.path=value (repeatable)");
  std::string frames;
  render->add_option("--frames", frames,
                     "frames A:B (both included) of an animated scene; default render.frames");

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
      "relMSE, SMAPE, MSE, PSNR of TEST against REF (two .exr files, or two folders of frames with "
      "the temporal-stability measure)");
  std::string cmp_ref, cmp_test, cmp_layer;
  bool cmp_json = false;
  cmp->add_option("reference", cmp_ref, "reference .exr or folder of frames")->required();
  cmp->add_option("test", cmp_test, "test .exr or folder of frames")->required();
  cmp->add_option("--layer", cmp_layer, "EXR layer to compare (default: R, G, B), e.g. volume, denoised");
  cmp->add_flag("--json", cmp_json, "print JSON");

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
  auto* info = vdbcmd->add_subcommand("info", "grids, types, bounds, voxel size, value range, memory");
  std::string info_file;
  bool info_json = false;
  info->add_option("file", info_file, ".vdb file")->required();
  info->add_flag("--json", info_json, "machine-readable output");

  auto* bench =
      app.add_subcommand("bench", "rays, samples and lookups per second; pass times against a copy kernel");
  haze::bench::Options bo;
  bench->add_flag("--json", bo.json, "print JSON instead of a table");
  bench->add_option("--size", bo.size, "image size WIDTHxHEIGHT");
  bench->add_option("--spp", bo.spp, "samples per measurement");
  bench->add_option("--denoise-sizes", bo.denoise_sizes, "sizes of the SVGF timings, WxH[,WxH...]");
  bench->add_option("--guiding-size", bo.guiding_size,
                    "image size of the guiding and volume denoiser figures");
  bench
      ->add_option("--guiding-seeds", bo.guiding_seeds,
                   "seeds of the guided/unguided comparison (0: skip it)")
      ->check(CLI::Range(0, 1000));

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }

  try {
    gpu::ContextOptions co = context_options(device, validation, pipeline_cache);
    if (list_devices) {
      for (const auto& d : gpu::list_devices()) fmt::print("{}\n", d.dump());
      return 0;
    }
    if (*render) return run_render(scene_path, out_dir, spp, size, frames, sets, co);
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
      haze::vdb::write_procedural(spec, vdb_out);
      fmt::print("wrote {}\n", vdb_out);
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
    if (*bench) return haze::bench::run(bo, co);
    if (*cmp) {
      nlohmann::json j = render::compare_paths(cmp_ref, cmp_test, cmp_layer);
      fmt::print("{}", cmp_json ? j.dump(2) + "\n" : render::format_comparison(j));
      return 0;
    }
    if (*dn) {
      nlohmann::json j = nlohmann::json::object();
      for (const auto& a : dn_sets) scene::apply_override(j, a, "--set");
      scene::Scene settings = scene::from_json(j, "--set", "");
      gpu::Context ctx(co);
      nlohmann::json st = render::denoise_sequence(ctx, dn_in, dn_out, settings);
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
