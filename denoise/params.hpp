// Parameters of one SVGF instance (docs/denoising.md), declared once: the scene's JSON
// (`denoise.surface.phi_luminance`), --set, the docs and stats.json all come from reflect() below.
#pragma once

#include <fmt/format.h>

#include <string>

#include "reflect/params.hpp"

namespace haze::denoise {

struct SvgfParams {
  bool enabled = true;
  std::string mode = "adaptive";  // adaptive | classic (Schied et al. 2017, its own constants)
  // Accumulation.
  float accumulate = 0.951f;  // a: alpha = max(1 - a, 1/n)
  float max_history = 32.f;
  float adapt_strength = 0.901f;  // s
  float adapt_ipr = 3.f;          // k_a
  float adapt_low = 0.190f, adapt_up = 0.907f;
  float firefly_bias = 0.2f, firefly_ipr = 50.f;
  float firefly_low = 0.25f, firefly_up = 0.90f;
  float firefly_max = 6.0e4f;  // hard clamp of the input luminance
  // What the reprojection tests and the edge-stopping terms compare: the surface G-buffer, or the signal's
  // own virtual points (their depth and its screen-space gradient; no normals), docs/denoising.md.
  std::string geometry = "surface";  // surface | virtual_points
  // Reprojection.
  float normal_threshold = 37.f;            // degrees
  float depth_tolerance = 0.0264f;          // tau, relative
  float border_history = 2.f;               // history cap when motion leaves the screen
  float history_test = 0.f;                 // k of the history's test against the neighbours' mean (0: off)
  std::string history_witness = "history";  // history | output: what the history test compares
  // What the next frame reprojects: the accumulated colour, or the first filter iteration's output (SVGF's
  // choice, which compounds the filter's blur and energy loss from frame to frame; classic mode always).
  std::string feedback = "accumulated";  // accumulated | filtered
  // Variance estimate.
  float variance_normal = 30.f;  // degrees
  float variance_depth = 40.f;
  float spatial_bias = 8.f, spatial_falloff = 3.f;
  // Filter.
  int iterations = 5;
  std::string kernel = "5x5";            // 5x5 | subsampled
  std::string normalization = "gather";  // gather (SVGF) | splat (energy-conserving)
  // What sigma steers the luminance term: one frame's sample (SVGF) or the accumulated estimate's.
  std::string filter_sigma = "sample";  // sample (SVGF) | estimate
  // Whose sigma scales the luminance term: the centre's (SVGF) or the pair's, the same both ways.
  std::string luminance_sigma = "pair";  // pair | centre (SVGF)
  // Width in pixels of the filter's epipolar term (0: off): taps away from the line through the pixel and the
  // image of the scene's one sun, point or spot light are cut, so the filter smooths along light shafts and
  // not across them.
  float epipolar = 0.f;
  float phi_luminance = 3.f;
  float phi_depth = 40.f;
  float phi_normal = 30.f;  // degrees
  float zbias_normal = 3000.f, zbias_depth = 0.f;
  // Temporal anti-aliasing.
  float taa_blend = 0.5f;            // weight of the clamped history
  std::string taa_clamp = "minmax";  // minmax | variance
  float taa_gamma = 1.f;
};

// The volume instance's starting parameters (docs/denoising.md, the table of starting parameters).
inline SvgfParams volume_defaults() {
  SvgfParams p;
  p.geometry = "virtual_points";
  p.filter_sigma = "estimate";
  p.normalization = "splat";
  p.luminance_sigma = "centre";
  p.feedback = "accumulated";
  p.history_witness = "output";
  p.accumulate = 0.5f;
  p.adapt_ipr = 3.f;
  p.adapt_low = 0.056f;
  p.adapt_up = 0.904f;
  p.firefly_up = 0.959f;
  p.normal_threshold = 180.f;
  p.depth_tolerance = 0.284f;
  p.history_test = 0.25f;
  p.adapt_strength = 0.f;
  p.iterations = 3;
  p.phi_luminance = 2.5f;
  p.phi_depth = 3968.f;
  p.phi_normal = 180.f;
  p.zbias_normal = 0.f;
  p.variance_normal = 180.f;
  p.variance_depth = 200.f;
  p.taa_blend = 0.65f;
  p.taa_clamp = "variance";
  p.taa_gamma = 0.75f;
  p.epipolar = 1.f;
  return p;
}

struct DenoiseSettings {
  SvgfParams surface;
  SvgfParams volume = volume_defaults();
  // Which motion vectors reproject the volume instance's history: the virtual points' projected forward
  // (volume motion), each pixel's own virtual point reprojected backward with the camera's motion (the
  // baseline), or the surface G-buffer's (an ablation).
  std::string volume_motion = "virtual_points";
};

template <class V>
void reflect(V& v, SvgfParams& p) {
  using reflection::Choices;
  using reflection::Range;
  v.field("enabled", p.enabled, "run this instance (it runs only where the scene has its signal)");
  v.field("mode", p.mode, Choices{"adaptive", "classic"},
          "adaptive: percentile-based SVGF; classic: Schied et al. 2017 with its constants (alpha 0.2, "
          "phi_l 4, phi_z 1, normal exponent 128); iterations, kernel and taa_* apply to both");
  v.field("accumulate", p.accumulate, Range{0, 1}, "a in alpha = max(1 - a, 1/n)");
  v.field("max_history", p.max_history, Range{1, 1024}, "history length cap (frames)");
  v.field("adapt_strength", p.adapt_strength, Range{0, 1}, "s: how strongly outdated history is cut");
  v.field("adapt_ipr", p.adapt_ipr, Range::at_least(0),
          "k_a: inter-percentile range factor of the adaptivity");
  v.field("adapt_low", p.adapt_low, Range{0, 1}, "lower adaptivity percentile");
  v.field("adapt_up", p.adapt_up, Range{0, 1}, "upper adaptivity percentile");
  v.field("firefly_bias", p.firefly_bias, Range::at_least(0), "bias of the firefly clamp");
  v.field("firefly_ipr", p.firefly_ipr, Range::at_least(0),
          "k_f: inter-percentile range factor of the clamp");
  v.field("firefly_low", p.firefly_low, Range{0, 1}, "lower firefly percentile");
  v.field("firefly_up", p.firefly_up, Range{0, 1}, "upper firefly percentile");
  v.field("firefly_max", p.firefly_max, Range{0, 6.5e4}, "hard clamp of the input luminance");
  v.field(
      "geometry", p.geometry, Choices{"surface", "virtual_points"},
      "what reprojection tests and edge stopping compare: the surface G-buffer's depth and normals, or the "
      "virtual point depth of the signal (and its gradient; volume instance only)");
  v.field("normal_threshold", p.normal_threshold, Range{0, 180}, "reprojection: max normal change, degrees");
  v.field("depth_tolerance", p.depth_tolerance, Range::at_least(0),
          "reprojection: |z - z'| <= tolerance * max(z, z')");
  v.field(
      "history_test", p.history_test, Range::at_least(0),
      "adaptive mode: a history whose luminance differs from this frame's 3x3 neighbours' mean by more than "
      "10% plus k standard errors is cut, to this frame's sample past 2k (0: off; the volume instance's "
      "reprojection with one virtual point per pixel is wrong where a ray crosses several sheets)");
  v.field(
      "history_witness", p.history_witness, Choices{"history", "output"},
      "adaptive mode, history_test > 0: what the test compares with the neighbours' mean, the reprojected "
      "history itself or the previous frame's denoised output at the same place (smooth: the test does not "
      "select on the history's own noise, which with skewed noise cuts bright histories more often than dark "
      "ones and loses energy); \"output\" needs an instance that does not remodulate (the volume)");
  v.field(
      "feedback", p.feedback, Choices{"accumulated", "filtered"},
      "adaptive mode: the next frame's colour history is this frame's temporal accumulation, or the first "
      "filter iteration's output as in SVGF (classic mode always), which feeds the filter's blur and "
      "energy loss back into the history");
  v.field("border_history", p.border_history, Range{1, 1024}, "history cap where motion leaves the screen");
  v.field("variance_normal", p.variance_normal, Range{0, 180}, "variance estimate: normal reject, degrees");
  v.field("variance_depth", p.variance_depth, Range::at_least(0), "variance estimate: depth scale");
  v.field("spatial_bias", p.spatial_bias, Range::at_least(0), "b in beta = clamp(b / n^f, 0, 1)");
  v.field("spatial_falloff", p.spatial_falloff, Range::at_least(0), "f in beta = clamp(b / n^f, 0, 1)");
  v.field("iterations", p.iterations, Range{0, 10}, "filter iterations (gap 2^i)");
  v.field("kernel", p.kernel, Choices{"5x5", "subsampled"}, "5x5 a-trous or the 6-tap subsampled pattern");
  v.field(
      "normalization", p.normalization, Choices{"gather", "splat"},
      "filter normalization (adaptive mode): gather divides each output by its weights' sum (SVGF); splat "
      "divides each input by the sum of the symmetric weights it gives away, which conserves the "
      "signal's sum exactly (one more pass per iteration)");
  v.field(
      "filter_sigma", p.filter_sigma, Choices{"sample", "estimate"},
      "adaptive mode: the luminance term's sigma is that of one frame's sample (SVGF) or of the accumulated "
      "estimate (the sample variance over the frames the colour averages), which stops at real edges once "
      "the history is long");
  v.field(
      "luminance_sigma", p.luminance_sigma, Choices{"centre", "pair"},
      "adaptive mode: the luminance term compares |Y_q - Y_p| with phi_l sigma_p, the centre's (SVGF), or "
      "with phi_l sqrt((sigma_p^2 + sigma_q^2) / 2), the spread of the difference, the same both ways (with "
      "the "
      "centre's, dark centres of skewed noise refuse bright neighbours that take them in: gather loses "
      "energy)");
  v.field("epipolar", p.epipolar, Range::at_least(0),
          "adaptive mode: width in pixels of the filter's epipolar term exp(-(e / width)^2), e the "
          "tap's distance from the line through the pixel and the image of the scene's one sun, point "
          "or spot light, along which in-scattered light varies slowly (0: off; off in scenes with "
          "another number of such lights)");
  v.field("phi_luminance", p.phi_luminance, Range::at_least(0), "luminance edge-stopping scale");
  v.field("phi_depth", p.phi_depth, Range::at_least(0), "depth edge-stopping scale");
  v.field("phi_normal", p.phi_normal, Range{0, 180}, "normal edge-stopping angle, degrees");
  v.field("zbias_normal", p.zbias_normal, Range::at_least(0),
          "distance where the normal term has faded (0: never)");
  v.field("zbias_depth", p.zbias_depth, Range::at_least(0),
          "distance where the depth term has faded (0: never)");
  v.field("taa_blend", p.taa_blend, Range{0, 1}, "TAA: weight of the clamped history");
  v.field("taa_clamp", p.taa_clamp, Choices{"minmax", "variance"},
          "TAA: clamp history to the 3x3 min/max box or to mean +- gamma sigma");
  v.field("taa_gamma", p.taa_gamma, Range::at_least(0), "TAA: gamma of the variance clamp");
}

inline void validate(SvgfParams& p, const reflection::Where& w) {
  if (!(p.adapt_low <= p.adapt_up))
    w.fail("adapt_up", fmt::format("must be >= adapt_low ({}), got {}", p.adapt_low, p.adapt_up));
  if (!(p.firefly_low <= p.firefly_up))
    w.fail("firefly_up", fmt::format("must be >= firefly_low ({}), got {}", p.firefly_low, p.firefly_up));
}

inline void validate(DenoiseSettings& d, const reflection::Where& w) {
  if (d.surface.history_witness == "output")
    w.fail("surface.history_witness",
           "the surface instance's output is remodulated by the albedo and carries emission, the history "
           "does not; only \"history\" is valid");
  if (d.surface.geometry != "surface")
    w.fail("surface.geometry",
           fmt::format("the surface instance has no virtual points; only \"surface\" is valid, got \"{}\"",
                       d.surface.geometry));
}

template <class V>
void reflect(V& v, DenoiseSettings& d) {
  v.field("surface", d.surface, "the surface instance (demodulated surface signal, surface G-buffer)");
  v.field("volume", d.volume, "the volume instance (light shafts; normal rejection off, weak depth terms)");
  v.field(
      "volume_motion", d.volume_motion, reflection::Choices{"virtual_points", "backward", "surface"},
      "motion vectors of the volume instance: the virtual points projected forward, each pixel's own "
      "virtual point reprojected into the previous camera (camera motion only, no forward projection), or "
      "the surface G-buffer's");
}

}  // namespace haze::denoise
