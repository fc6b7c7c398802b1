#version 460
// Exposure and tonemapping of the denoised frame: composite = surface signal (with its transmittance) +
// volume signal, scaled by the exposure, tone-curved and sRGB-encoded into the 8-bit preview. Each signal
// is an SVGF instance's output (half rgb + sigma per pixel) or floats with a stride and offset per pixel.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;
#include "common/color.glsl"
#include "common/dispatch.glsl"

layout(constant_id = 0) const uint SURFACE_HALF = 1u;  // 1: the surface signal is an SVGF output
layout(constant_id = 1) const uint VOLUME_HALF = 0u;   // 1: the volume signal is an SVGF output

layout(std430, binding = BINDING_surface) readonly buffer Surface {
  uint surface[];
};
layout(std430, binding = BINDING_volume) readonly buffer Volume {
  uint volume[];
};
layout(std430, binding = BINDING_ldr) writeonly buffer Ldr {
  uint ldr[];
};

layout(push_constant) uniform Push {
  uint pixels;
  uint surface_stride, surface_offset;  // floats per pixel, rgb at offset (float inputs only)
  uint volume_stride, volume_offset;
  float exposure_scale;
  uint tonemap;  // 0 aces, 1 reinhard, 2 clamp
}
pc;

vec3 half_rgb(uint a, uint b) {
  return vec3(unpackHalf2x16(a), unpackHalf2x16(b).x);
}

vec3 float_rgb(uint a, uint b, uint c) {
  return uintBitsToFloat(uvec3(a, b, c));
}

void main() {
  uint p = invocation_index();
  if (p >= pc.pixels) return;
  vec3 s, v;
  if (SURFACE_HALF != 0u) {
    s = half_rgb(surface[2u * p], surface[2u * p + 1u]);
  } else {
    uint i = p * pc.surface_stride + pc.surface_offset;
    s = float_rgb(surface[i], surface[i + 1u], surface[i + 2u]);
  }
  if (VOLUME_HALF != 0u) {
    v = half_rgb(volume[2u * p], volume[2u * p + 1u]);
  } else {
    uint i = p * pc.volume_stride + pc.volume_offset;
    v = float_rgb(volume[i], volume[i + 1u], volume[i + 2u]);
  }
  ldr[p] = pack_srgb8(tonemap((s + v) * pc.exposure_scale, pc.tonemap));
}
