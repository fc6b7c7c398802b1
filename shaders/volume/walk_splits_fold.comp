#version 460
// After each trace dispatch with learned walk splits (docs/rendering.md, "Split walks"): adds what the
// dispatch learned to the totals the next one reads, and empties it.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8) in;
#include "volume/walk_splits_layout.glsl"

layout(std430, binding = BINDING_split_stats) buffer SplitStats {
  float split_stats[];
};

void main() {
  uint i = gl_LocalInvocationID.x;
  split_stats[SPLIT_TOTALS + i] += split_stats[SPLIT_LEARN + i];
  split_stats[SPLIT_LEARN + i] = 0.0f;
}
