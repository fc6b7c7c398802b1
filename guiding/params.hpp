// Parameters of distance guiding (docs/guiding.md), declared once: the scene's JSON
// (`guiding.probability`),
// --set, the docs and stats.json all come from reflect() below.
#pragma once

#include <string>

#include "reflect/params.hpp"

namespace haze::guiding {

struct GuidingParams {
  bool enabled = false;
  std::string model = "histogram";  // a histogram per vertex, or K Gaussian states (docs/guiding.md)
  int bins = 64;                    // histogram: bins over the guided segment [0, t_g]
  bool choose_probability = true;   // histogram: P per vertex from the learned second moments
  float probability = 0.5f;         // P in q(t) = (1 - P) q_base + P q_guide
  int spacing = 10;                 // pixels between grid vertices (measured for the histogram)
  int states = 10;                  // K states per vertex
  int candidates = 3;               // C candidates per distance sample
  float min_width = 0.005f;         // floor of the guide's sigma, relative to the ray's [0, t_s]
  float prior_width = 0.1f;         // sigma the prior pulls towards while a state has few samples, relative
  float prior_count = 4.f;          // samples' worth of weight of that prior
  int max_count = 1024;             // N cap: alpha = max(1/N, min_alpha)
  float min_alpha = 0.01f;
  bool learn = true;     // update the states (off: sample from them as they are)
  bool temporal = true;  // carry the states to the next frame through the volume motion
};

// Compile-time bound of the candidate loop in the shader (guide.glsl GUIDE_MAX_CANDIDATES).
inline constexpr int kMaxGuideCandidates = 8;
// The P a histogram vertex chooses from (guide.glsl guide_p_choice, GUIDE_P_CHOICES).
inline constexpr int kGuideProbabilityChoices = 5;

template <class V>
void reflect(V& v, GuidingParams& p) {
  using reflection::Range;
  v.field("enabled", p.enabled,
          "learn and sample distances along camera rays (only where the scene has media and lights)");
  v.field("model", p.model, reflection::Choices{"histogram", "gaussian"},
          "histogram: one histogram of contributions over the ray per grid vertex, sampled piecewise "
          "constant; gaussian: K Gaussian states per vertex (a Markov chain of states)");
  v.field("bins", p.bins, Range{2, 256}, "histogram: bins over the guided segment of each ray");
  v.field("choose_probability", p.choose_probability,
          "histogram: each vertex chooses P in {0, 0.25, 0.5, 0.75, 0.9} by the learned second moments "
          "(off: probability everywhere)");
  v.field("probability", p.probability, Range{0, 0.99},
          "P: share of distance samples drawn from the guide (the rest from transmittance)");
  v.field("spacing", p.spacing, Range{1, 4096}, "pixels between the guide's grid vertices");
  v.field("states", p.states, Range{1, 64}, "K: states per grid vertex");
  v.field("candidates", p.candidates, Range{1, kMaxGuideCandidates}, "C: candidate states per sample");
  v.field("min_width", p.min_width, Range{1e-6, 1}, "smallest sigma, relative to the ray segment");
  v.field("prior_width", p.prior_width, Range{1e-6, 10}, "sigma of the prior, relative to the ray segment");
  v.field("prior_count", p.prior_count, Range::at_least(0), "weight of the prior in samples");
  v.field("max_count", p.max_count, Range{1, 1 << 20}, "cap of a state's sample count N");
  v.field("min_alpha", p.min_alpha, Range{0, 1}, "alpha = max(1/N, min_alpha) in the running means");
  v.field("learn", p.learn, "update the states from each sample's contribution");
  v.field("temporal", p.temporal, "carry the states to the next frame through the volume motion vectors");
}

}  // namespace haze::guiding
