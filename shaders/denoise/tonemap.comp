#version 460
// Exposure and tonemapping of the denoised frame: composite = denoised surface signal + volume signal,
// scaled by the exposure, tone-curved and sRGB-encoded into the 8-bit preview.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;

#include "common/color.glsl"

layout(std430, binding = 0) readonly buffer Surface {
  uvec2 surface[];  // half rgb, sigma (an SVGF instance's output)
};
layout(std430, binding = 1) readonly buffer Volume {
  float volume[];  // stride floats per pixel, rgb at offset
};
layout(std430, binding = 2) writeonly buffer Ldr {
  uint ldr[];
};

layout(push_constant) uniform Push {
  uint pixels;
  uint volume_stride;
  uint volume_offset;
  float exposure_scale;
  uint tonemap;  // 0 aces, 1 reinhard, 2 clamp
}
pc;

void main() {
  uint p = gl_GlobalInvocationID.x;
  if (p >= pc.pixels) return;
  vec3 s = vec3(unpackHalf2x16(surface[p].x), unpackHalf2x16(surface[p].y).x);
  uint v = p * pc.volume_stride + pc.volume_offset;
  vec3 L = s + vec3(volume[v], volume[v + 1u], volume[v + 2u]);
  ldr[p] = pack_srgb8(tonemap(L * pc.exposure_scale, pc.tonemap));
}
