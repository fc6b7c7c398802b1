#version 460
// Per-pixel means of the accumulated sums, the sample variance of the final radiance, the virtual point
// depth, and the tonemapped 8-bit preview.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;

#include "common/color.glsl"
#include "common/compat.glsl"
#include "volume/gpu_scene.glsl"

layout(std430, binding = 0) readonly buffer AccumBuffer {
  float accum[];
};
layout(std430, binding = 1) writeonly buffer OutBuffer {
  float outp[];
};
layout(std430, binding = 2) writeonly buffer LdrBuffer {
  uint ldr[];
};

layout(push_constant) uniform Push {
  uint pixels;
  uint samples;
  float exposure_scale;
  uint tonemap;  // 0 aces, 1 reinhard, 2 clamp
}
pc;

void main() {
  uint p = gl_GlobalInvocationID.x;
  if (p >= pc.pixels) return;
  uint a = p * ACC_STRIDE, o = p * OUT_STRIDE;
  float n = float(max(pc.samples, 1u));
  for (uint k = 0u; k < 11u; ++k) outp[o + k] = accum[a + k] / n;
  vec3 mean = vec3(accum[a + ACC_L], accum[a + ACC_L + 1], accum[a + ACC_L + 2]) / n;
  vec3 m2 = vec3(accum[a + ACC_L2], accum[a + ACC_L2 + 1], accum[a + ACC_L2 + 2]) / n;
  vec3 var = pc.samples > 1u ? max(m2 - mean * mean, vec3(0.0f)) * (n / (n - 1.0f)) : vec3(0.0f);
  for (uint c = 0u; c < 3u; ++c) {
    outp[o + OUT_VAR + c] = var[c];
    outp[o + OUT_DEMOD + c] = accum[a + ACC_DEMOD + c] / n;
    outp[o + OUT_DEMOD_M2 + c] = accum[a + ACC_DEMOD2 + c] / n;
  }

  // Virtual point depth: where the volume contribution concentrates, else the guide's mean, else the depth.
  float vp = accum[a + ACC_DEPTH] / n;
  if (accum[a + ACC_VP_W] > 0.0f)
    vp = accum[a + ACC_VP_WT] / accum[a + ACC_VP_W];
  else if (accum[a + ACC_VP_GN] > 0.0f)
    vp = accum[a + ACC_VP_G] / accum[a + ACC_VP_GN];
  outp[o + OUT_VPDEPTH] = vp;

  ldr[p] = pack_srgb8(tonemap(mean * pc.exposure_scale, pc.tonemap));
}
