#include "bench/shafts_bench.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <numeric>

#include "eval/flip.hpp"
#include "eval/metrics.hpp"
#include "eval/reference.hpp"
#include "render/run.hpp"
#include "scene/scene.hpp"

namespace haze::bench {

namespace fs = std::filesystem;
using nlohmann::json;

json shafts_scene(const ShaftsOptions& o) {
  // A wall of vertical planks at z = 0 (1 m apart, 0.4 m gaps), a floor and a ceiling that keep the sun out
  // of the room except through the gaps; the sun low behind the wall, so the sheets slant down into the
  // room and end in stripes on the floor.
  json surfaces = {{{"mesh", {{"kind", "box"}, {"size", {12, 0.1, 10}}}},
                    {"transform", {{"translate", {0, -0.05, 4}}}},
                    {"albedo", {0.6, 0.6, 0.6}}},
                   {{"mesh", {{"kind", "box"}, {"size", {12, 0.1, 9.4}}}},
                    {"transform", {{"translate", {0, 3.05, 4.6}}}},
                    {"albedo", {0.5, 0.5, 0.5}}}};
  for (int k = -5; k < 5; ++k)
    surfaces.push_back({{"mesh", {{"kind", "box"}, {"size", {0.6, 3.1, 0.1}}}},
                        {"transform", {{"translate", {k + 0.5, 1.5, 0}}}},
                        {"albedo", {0.55, 0.45, 0.35}}});
  // The move is defined over 24 frames whatever the number rendered, so that its speed per frame is fixed.
  const int last = 23;
  json j = {
      {"camera", {{"position", {2.6, 1.3, 6.0}}, {"target", {-0.6, 1.3, 1.2}}, {"fov_y", 55}}},
      {"surfaces", surfaces},
      // The puff: a small procedural cloud drifting through the sheets.
      {"media",
       {{{"procedural",
          {{"kind", "cloud"},
           {"voxel_size", 0.04},
           {"center", {0, 0, 0}},
           {"size", {1, 1, 1}},
           {"density", 3},
           {"falloff", 0.6},
           {"frequency", 2},
           {"seed", 5}}},
         {"albedo", {0.9, 0.9, 0.9}},
         {"g", 0.3},
         {"transform", {{"translate", {-1.0, 1.4, 2.5}}}}}}},
      {"haze",
       {{"sigma_t", 0.15},
        {"albedo", {0.9, 0.9, 0.9}},
        {"g", 0.3},
        {"bounded", true},
        {"bounds_min", {-6, 0, 0.05}},
        {"bounds_max", {6, 3, 9}}}},
      {"lights",
       {{"sun", {{"direction", {-0.35, 0.55, -1}}, {"irradiance", 10}, {"angular_diameter", 0}}},
        {"environment", {{"color", {0.3, 0.35, 0.45}}, {"intensity", 0.1}}}}},
      {"guiding", {{"enabled", true}, {"probability", 0.5}}},
      {"render",
       {{"width", o.width},
        {"height", o.height},
        {"spp", o.spp},
        {"max_depth", 1},
        {"frames", fmt::format("0:{}", std::max(0, o.frames - 1))}}},
      {"animation",
       {{"tracks",
         {{{"path", "camera.position"},
           {"keys",
            {{{"frame", 0}, {"value", {2.6, 1.3, 6.0}}}, {{"frame", last}, {"value", {1.0, 1.4, 6.4}}}}}},
          {{"path", "media[0].transform.translate"},
           {"keys",
            {{{"frame", 0}, {"value", {-1.0, 1.4, 2.5}}},
             {{"frame", last}, {"value", {1.0, 1.2, 3.0}}}}}}}}}}};
  return j;
}

std::vector<int8_t> sheet_masks(const std::vector<float>& Y, int W, int H, int radius) {
  // Box means through a summed-area table.
  std::vector<double> sat(size_t(W + 1) * (H + 1), 0.0);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      sat[size_t(y + 1) * (W + 1) + x + 1] = Y[size_t(y) * W + x] + sat[size_t(y) * (W + 1) + x + 1] +
                                             sat[size_t(y + 1) * (W + 1) + x] - sat[size_t(y) * (W + 1) + x];
  const double mean = std::accumulate(Y.begin(), Y.end(), 0.0) / double(Y.size());
  std::vector<int8_t> m(Y.size(), 0);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const int x0 = std::max(0, x - radius), x1 = std::min(W, x + radius + 1);
      const int y0 = std::max(0, y - radius), y1 = std::min(H, y + radius + 1);
      const double box = (sat[size_t(y1) * (W + 1) + x1] - sat[size_t(y0) * (W + 1) + x1] -
                          sat[size_t(y1) * (W + 1) + x0] + sat[size_t(y0) * (W + 1) + x0]) /
                         double((x1 - x0) * (y1 - y0));
      if (box < 0.05 * mean) continue;
      const double v = Y[size_t(y) * W + x];
      m[size_t(y) * W + x] = v > 1.25 * box ? 1 : (v < 0.8 * box ? -1 : 0);
    }
  return m;
}

double sheet_contrast(const std::vector<float>& Y, const std::vector<int8_t>& mask) {
  double in = 0, out = 0;
  size_t n_in = 0, n_out = 0;
  for (size_t p = 0; p < Y.size(); ++p) {
    if (mask[p] > 0) in += Y[p], ++n_in;
    if (mask[p] < 0) out += Y[p], ++n_out;
  }
  if (!n_in || !n_out || out <= 0) return 0;
  return (in / double(n_in)) / (out / double(n_out));
}

double block_ratio(const std::vector<float>& Y, int W, int H) {
  double on = 0, off = 0;
  size_t n_on = 0, n_off = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float v = Y[size_t(y) * W + x];
      if (x > 0) {
        const double d = std::abs(v - Y[size_t(y) * W + x - 1]);
        (x % 8 == 0 ? on : off) += d;
        ++(x % 8 == 0 ? n_on : n_off);
      }
      if (y > 0) {
        const double d = std::abs(v - Y[size_t(y - 1) * W + x]);
        (y % 8 == 0 ? on : off) += d;
        ++(y % 8 == 0 ? n_on : n_off);
      }
    }
  return n_on && n_off && off > 0 ? (on / double(n_on)) / (off / double(n_off)) : 1.0;
}

std::vector<float> luminance_of(const std::vector<glm::vec3>& rgb) {
  std::vector<float> Y(rgb.size());
  for (size_t p = 0; p < rgb.size(); ++p) Y[p] = glsl::luminance(rgb[p]);
  return Y;
}

namespace {

std::vector<glm::vec3> planes_rgb(const render::ExrImage& img, const std::string& layer) {
  const std::string pre = layer.empty() ? "" : layer + ".";
  const auto &r = img.channel(pre + "R"), &g = img.channel(pre + "G"), &b = img.channel(pre + "B");
  std::vector<glm::vec3> out(r.size());
  for (size_t p = 0; p < r.size(); ++p) out[p] = {r[p], g[p], b[p]};
  return out;
}

std::vector<glm::vec3> layer_rgb(const render::Image& img, uint32_t offset) {
  std::vector<glm::vec3> out(size_t(img.width) * img.height);
  for (size_t p = 0; p < out.size(); ++p) {
    const float* d = &img.data[p * glsl::OUT_STRIDE + offset];
    out[p] = {d[0], d[1], d[2]};
  }
  return out;
}

eval::Channels channels(const std::vector<glm::vec3>& v) {
  return {&v[0].x, v.size(), 3, 0, 3};
}

double mean_luminance(const std::vector<glm::vec3>& v) {
  double s = 0;
  for (const auto& c : v) s += glsl::luminance(c);
  return s / double(v.size());
}

// a / b where b > 0 and the quotient is finite, else null (a frame too small or too dark to say).
json ratio(double a, double b) {
  return b > 0 && std::isfinite(a / b) ? json(a / b) : json();
}

json minus_one(const json& r) {
  return r.is_number() ? json(r.get<double>() - 1) : json();
}

double number_or_nan(const json& j) {
  return j.is_number() ? j.get<double>() : std::nan("");
}

json summary_of(const std::vector<double>& v) {
  if (v.empty()) return json::object();
  const double mean = std::accumulate(v.begin(), v.end(), 0.0) / double(v.size());
  return {{"mean", mean},
          {"min", *std::min_element(v.begin(), v.end())},
          {"max", *std::max_element(v.begin(), v.end())}};
}

void write_preview(const std::string& path, int W, int H, const std::vector<glm::vec3>& rgb) {
  std::vector<float> f(rgb.size() * 3);
  for (size_t p = 0; p < rgb.size(); ++p)
    for (int c = 0; c < 3; ++c) f[p * 3 + c] = rgb[p][c];
  render::write_png_rgb8(path, W, H, render::preview_srgb8(f, 1.0f, "aces"));
}

std::string default_cache() {
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x)
    return (fs::path(x) / "haze/references").string();
  if (const char* h = std::getenv("HOME"); h && *h) return (fs::path(h) / ".cache/haze/references").string();
  return (fs::temp_directory_path() / "haze-references").string();
}

}  // namespace

json bench_shafts(gpu::Context& ctx, const ShaftsOptions& o) {
  json sj = shafts_scene(o);
  if (!o.set.is_null()) sj.merge_patch(o.set);
  const scene::Scene s = scene::from_json(sj, "shafts bench scene", "");
  const int W = s.render.width, H = s.render.height;
  const size_t pixels = size_t(W) * H;

  // The converged reference of every frame, cached under its key.
  scene::Scene rs = s;
  rs.render.volume_samples = o.reference_volume_samples;
  eval::ReferenceOptions ro;
  ro.target = 0.05;
  ro.min_spp = ro.max_spp = o.reference_spp;
  const std::string dir = (fs::path(o.reference_dir.empty() ? default_cache() : o.reference_dir) /
                           ("shafts-" + eval::reference_key(eval::reference_scene(rs), ro)))
                              .string();
  json ref_info;
  {
    std::unique_ptr<render::Renderer> rr;
    ref_info = eval::make_reference(ctx, rs, 0, o.frames - 1, dir, ro, {}, rr);
  }
  double ref_error = 0;
  for (const auto& [k, v] : ref_info["frames"].items())
    ref_error = std::max(ref_error, v.value("error_quantile", 0.0));

  const bool vp_motion = s.denoise.volume_motion != "surface";
  std::unique_ptr<render::Renderer> r;
  std::vector<std::vector<glm::vec3>> seq_comp, seq_vol, ref_comp, ref_vol;
  std::vector<float> prev_ref_Y;
  json frames = json::array();
  std::vector<double> contrast_after4, mean_surface, mean_volume;
  std::vector<std::vector<int8_t>> masks;
  std::vector<double> contrast_refs;
  for (int f = 0; f < o.frames; ++f) {
    render::use_frame(ctx, r, s, f, f == 0);
    r->add_samples(o.spp);
    const render::Image img = r->resolve();
    const render::ExrImage ref = render::read_exr(eval::reference_frame_path(dir, f));
    const std::vector<glm::vec3> r_L = planes_rgb(ref, ""), r_vol = planes_rgb(ref, "volume"),
                                 r_surf = planes_rgb(ref, "surface");
    const std::vector<glm::vec3> n_L = layer_rgb(img, glsl::OUT_L), n_vol = layer_rgb(img, glsl::OUT_VOL),
                                 n_surf = layer_rgb(img, glsl::OUT_SURF);
    const std::vector<glm::vec3>& d_surf = img.surface_denoised ? img.surface_denoised->colour : n_surf;
    const std::vector<glm::vec3>& d_vol = img.volume_denoised ? img.volume_denoised->colour : n_vol;
    std::vector<glm::vec3> d_L(pixels);
    for (size_t p = 0; p < pixels; ++p) d_L[p] = d_surf[p] + d_vol[p];

    const std::vector<float> Y_ref = luminance_of(r_vol);
    const std::vector<int8_t> mask = sheet_masks(Y_ref, W, H, std::max(2, W / 24));
    const double c_ref = sheet_contrast(Y_ref, mask);
    const double c_dn = sheet_contrast(luminance_of(d_vol), mask);
    const double c_noisy = sheet_contrast(luminance_of(n_vol), mask);
    masks.push_back(mask);
    contrast_refs.push_back(c_ref);
    const json c_comp =
        ratio(sheet_contrast(luminance_of(d_L), mask), sheet_contrast(luminance_of(r_L), mask));
    size_t in = 0, between = 0;
    for (int8_t m : mask) in += m > 0, between += m < 0;

    // Volume history where the reprojection is wrong: the reference's volume luminance at the reprojected
    // position of the previous frame differs from this pixel's by more than 30% (of the larger).
    json hist = json::object();
    if (img.volume_denoised && f > 0) {
      double h_wrong = 0, h_right = 0;
      size_t n_wrong = 0, n_right = 0;
      const double floor = 0.02 * std::accumulate(Y_ref.begin(), Y_ref.end(), 0.0) / double(pixels);
      for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) {
          const size_t p = size_t(y) * W + x;
          const glm::vec2 mv = vp_motion && !img.volume_motion.empty()
                                   ? glm::vec2(img.volume_motion[p])
                                   : glm::vec2(img.g(x, y, glsl::G_MOTION), img.g(x, y, glsl::G_MOTION + 1));
          const glm::vec2 q = glm::vec2(x, y) + mv;  // pixel-centre offsets cancel
          const int qx = int(std::lround(q.x)), qy = int(std::lround(q.y));
          if (qx < 0 || qy < 0 || qx >= W || qy >= H) continue;
          const double a = Y_ref[p], b = prev_ref_Y[size_t(qy) * W + qx];
          const bool wrong = std::abs(a - b) > 0.3 * std::max(a, b) + floor;
          (wrong ? h_wrong : h_right) += img.volume_denoised->history[p];
          ++(wrong ? n_wrong : n_right);
        }
      hist = {{"wrong_share", double(n_wrong) / double(n_wrong + n_right)},
              {"mean_where_wrong", n_wrong ? h_wrong / double(n_wrong) : 0.0},
              {"mean_where_right", n_right ? h_right / double(n_right) : 0.0}};
    }
    prev_ref_Y = Y_ref;

    const json m_surf = minus_one(ratio(mean_luminance(d_surf), mean_luminance(r_surf)));
    const json m_vol = minus_one(ratio(mean_luminance(d_vol), mean_luminance(r_vol)));
    json fr = {{"frame", f},
               {"relmse",
                {{"composite", eval::relmse(channels(d_L), channels(r_L))},
                 {"composite_noisy", eval::relmse(channels(n_L), channels(r_L))},
                 {"volume", eval::relmse(channels(d_vol), channels(r_vol))},
                 {"volume_noisy", eval::relmse(channels(n_vol), channels(r_vol))}}},
               {"flip_ldr",
                {{"composite", eval::flip_ldr(channels(d_L), channels(r_L), W, H).mean},
                 {"composite_noisy", eval::flip_ldr(channels(n_L), channels(r_L), W, H).mean},
                 {"volume", eval::flip_ldr(channels(d_vol), channels(r_vol), W, H).mean},
                 {"volume_noisy", eval::flip_ldr(channels(n_vol), channels(r_vol), W, H).mean}}},
               {"sheet_contrast",
                {{"reference", c_ref},
                 {"volume_over_reference", ratio(c_dn, c_ref)},
                 {"noisy_volume_over_reference", ratio(c_noisy, c_ref)},
                 {"composite_over_reference", c_comp},
                 {"pixels_in", in},
                 {"pixels_between", between}}},
               {"mean_luminance_over_reference",
                {{"surface", m_surf},
                 {"volume", m_vol},
                 {"surface_noisy", minus_one(ratio(mean_luminance(n_surf), mean_luminance(r_surf)))},
                 {"volume_noisy", minus_one(ratio(mean_luminance(n_vol), mean_luminance(r_vol)))}}},
               {"volume_history", hist},
               {"block_ratio",
                {{"volume", block_ratio(luminance_of(d_vol), W, H)},
                 {"composite", block_ratio(luminance_of(d_L), W, H)},
                 {"volume_reference", block_ratio(Y_ref, W, H)}}}};
    frames.push_back(fr);
    if (f >= 4 && ratio(c_dn, c_ref).is_number()) contrast_after4.push_back(c_dn / c_ref - 1);
    if (m_surf.is_number()) mean_surface.push_back(m_surf.get<double>());
    if (m_vol.is_number()) mean_volume.push_back(m_vol.get<double>());
    seq_comp.push_back(d_L);
    seq_vol.push_back(d_vol);
    ref_comp.push_back(r_L);
    ref_vol.push_back(r_vol);

    if (!o.images_dir.empty() && (f == 0 || f == 4 || f == o.frames - 1)) {
      render::ensure_writable_dir(o.images_dir);
      auto png = [&](const char* what, const std::vector<glm::vec3>& v) {
        write_preview((fs::path(o.images_dir) / fmt::format("{}_f{}_{}.png", o.label, f, what)).string(), W,
                      H, v);
      };
      png("denoised", d_L);
      png("noisy", n_L);
      png("reference", r_L);
      png("volume_denoised", d_vol);
      png("volume_noisy", n_vol);
      png("volume_reference", r_vol);
    }
  }
  // The same sequence with the volume instance reduced to its temporal accumulation (no filter, no TAA, no
  // history cap or test, the accumulation as its own history): the sheet contrast that the reprojection
  // alone keeps, the floor under what the spatial passes and the history's tests can reach.
  std::vector<double> floor_after4;
  if (o.accumulation_floor && s.denoise.volume.enabled && !masks.empty()) {
    scene::Scene fs = s;
    fs.denoise.volume.iterations = 0;
    fs.denoise.volume.taa_blend = 0.f;
    fs.denoise.volume.feedback = "accumulated";
    fs.denoise.volume.history_test = 0.f;
    fs.denoise.volume.adapt_strength = 0.f;
    std::unique_ptr<render::Renderer> fr;
    for (int f = 0; f < o.frames; ++f) {
      render::use_frame(ctx, fr, fs, f, f == 0);
      fr->add_samples(o.spp);
      const render::Image img = fr->resolve();
      if (!img.volume_denoised) break;
      const double c = sheet_contrast(luminance_of(img.volume_denoised->colour), masks[size_t(f)]);
      const json over = ratio(c, contrast_refs[size_t(f)]);
      frames[size_t(f)]["sheet_contrast"]["accumulation_only_over_reference"] = over;
      if (f >= 4 && over.is_number()) floor_after4.push_back(over.get<double>() - 1);
    }
  }

  std::vector<eval::Channels> a, b, c, d;
  for (int f = 0; f < o.frames; ++f) {
    a.push_back(channels(seq_comp[size_t(f)]));
    b.push_back(channels(ref_comp[size_t(f)]));
    c.push_back(channels(seq_vol[size_t(f)]));
    d.push_back(channels(ref_vol[size_t(f)]));
  }
  return {{"scene", sj},
          {"size", {W, H}},
          {"frames", o.frames},
          {"spp", o.spp},
          {"reference",
           {{"dir", dir},
            {"spp", o.reference_spp},
            {"volume_samples", o.reference_volume_samples},
            {"worst_error_quantile", ref_error}}},
          {"volume_geometry", s.denoise.volume.geometry},
          {"volume_motion", s.denoise.volume_motion},
          {"per_frame", frames},
          {"contrast_error_from_frame_4", summary_of(contrast_after4)},
          {"contrast_error_accumulation_only_from_frame_4", summary_of(floor_after4)},
          {"mean_error_surface", summary_of(mean_surface)},
          {"mean_error_volume", summary_of(mean_volume)},
          {"temporal",
           {{"composite", eval::temporal(a, b).to_json()}, {"volume", eval::temporal(c, d).to_json()}}}};
}

void print_shafts(const json& j) {
  fmt::print(
      "shafts at {}x{}, {} frames of {} spp (reference {} spp x {} volume samples; volume geometry {}, "
      "motion {})\n",
      j["size"][0].get<int>(), j["size"][1].get<int>(), j["frames"].get<int>(), j["spp"].get<int>(),
      j["reference"]["spp"].get<int>(), j["reference"]["volume_samples"].get<int>(),
      j["volume_geometry"].get<std::string>(), j["volume_motion"].get<std::string>());
  fmt::print("  {:>3} {:>15} {:>13} {:>15} {:>13} {:>9} {:>9} {:>9} {:>8} {:>8} {:>11}\n", "f", "relMSE comp",
             "FLIP comp", "relMSE vol", "FLIP vol", "contrast", "acc.only", "cmp.cont", "mean S", "mean V",
             "hist w/r");
  for (const auto& f : j["per_frame"]) {
    const auto &rm = f["relmse"], &fl = f["flip_ldr"], &c = f["sheet_contrast"],
               &m = f["mean_luminance_over_reference"], &h = f["volume_history"];
    fmt::print(
        "  {:>3} {:>7.3f}/{:<7.3f} {:>6.3f}/{:<6.3f} {:>7.3f}/{:<7.3f} {:>6.3f}/{:<6.3f} {:>+8.1f}% "
        "{:>+8.1f}% {:>+8.1f}% {:>+7.1f}% {:>+7.1f}% {:>5.1f}/{:<5.1f}\n",
        f["frame"].get<int>(), rm["composite"].get<double>(), rm["composite_noisy"].get<double>(),
        fl["composite"].get<double>(), fl["composite_noisy"].get<double>(), rm["volume"].get<double>(),
        rm["volume_noisy"].get<double>(), fl["volume"].get<double>(), fl["volume_noisy"].get<double>(),
        100 * (number_or_nan(c["volume_over_reference"]) - 1),
        100 * (number_or_nan(c.value("accumulation_only_over_reference", json())) - 1),
        100 * (number_or_nan(c["composite_over_reference"]) - 1), 100 * number_or_nan(m["surface"]),
        100 * number_or_nan(m["volume"]), h.value("mean_where_wrong", 0.0), h.value("mean_where_right", 0.0));
  }
  fmt::print(
      "  (denoised/noisy; contrast: the sheets' contrast in the denoised volume term and composite against "
      "the reference's; acc.only: the volume's contrast from its temporal accumulation alone, the "
      "reprojection's floor; mean: denoised surface and volume against the reference's; hist: volume "
      "history where the reprojection is wrong / right)\n");
  const auto& b0 = j["per_frame"][0]["block_ratio"];
  fmt::print(
      "  8x8 block pattern at frame 0 (steps across the 8x8 grid / other steps): denoised volume {:.3f}, "
      "composite {:.3f}, reference volume {:.3f}\n",
      b0["volume"].get<double>(), b0["composite"].get<double>(), b0["volume_reference"].get<double>());
  const auto& t = j["temporal"];
  fmt::print(
      "  temporal stability, change ratio (1: as much change as the reference): composite {:.3f}, volume "
      "{:.3f}\n",
      t["composite"]["change_ratio"].get<double>(), t["volume"]["change_ratio"].get<double>());
}

}  // namespace haze::bench
