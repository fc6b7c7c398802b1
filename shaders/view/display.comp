#version 460
// The viewer's layer display: one layer of the frame as the window's 8-bit RGBA image. Colours go through
// the preview's exposure, tone curve and sRGB (common/color.glsl, as the PNG preview); data layers map to
// grey or to red-green with a scale the host chooses (docs/viewer.md, layers).
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;
#include "common/color.glsl"
#include "common/dispatch.glsl"
#include "common/packing.glsl"

layout(std430, binding = BINDING_src) readonly buffer Src {
  uint src[];
};
layout(std430, binding = BINDING_display) writeonly buffer Display {
  uint display[];
};

const uint COLOUR = 0u;       // rgb floats at offset
const uint COLOUR_HALF = 1u;  // an SVGF output: half rgb + sigma per pixel
const uint SCALAR = 2u;       // one float at offset, grey = value * scale
const uint MOTION = 3u;       // two floats at offset (pixels), red-green = 0.5 + 0.5 * value * scale
const uint NORMAL = 4u;       // octahedral normal at offset, rgb = 0.5 + 0.5 n
const uint GUIDE = 5u;        // the guide's states: the nearest vertex's contribution-weighted mean distance

layout(push_constant) uniform Push {
  uint pixels, width, mode, stride;  // stride: floats per pixel (per state for GUIDE)
  uint offset;
  float scale, exposure_scale;
  uint tonemap;
  uvec4 guide;  // x, y: vertices across and down, z: spacing in pixels, w: K states per vertex
}
pc;

float at(uint i) {
  return uintBitsToFloat(src[i]);
}

uint pack_unorm8(vec3 c) {
  uvec3 c8 = uvec3(round(clamp(c, vec3(0.0f), vec3(1.0f)) * 255.0f));
  return c8.r | (c8.g << 8u) | (c8.b << 16u) | (255u << 24u);
}

void main() {
  uint p = invocation_index();
  if (p >= pc.pixels) return;
  uint i = p * pc.stride + pc.offset;
  uint out_value;
  if (pc.mode == COLOUR) {
    out_value = pack_srgb8(tonemap(vec3(at(i), at(i + 1u), at(i + 2u)) * pc.exposure_scale, pc.tonemap));
  } else if (pc.mode == COLOUR_HALF) {
    vec3 c = vec3(unpackHalf2x16(src[2u * p]), unpackHalf2x16(src[2u * p + 1u]).x);
    out_value = pack_srgb8(tonemap(c * pc.exposure_scale, pc.tonemap));
  } else if (pc.mode == SCALAR) {
    out_value = pack_srgb8(vec3(clamp(at(i) * pc.scale, 0.0f, 1.0f)));
  } else if (pc.mode == MOTION) {
    vec2 m = clamp(vec2(at(i), at(i + 1u)) * pc.scale, vec2(-1.0f), vec2(1.0f));
    out_value = pack_unorm8(vec3(0.5f + 0.5f * m, 0.5f));
  } else if (pc.mode == NORMAL) {
    out_value = pack_unorm8(0.5f + 0.5f * oct_decode(vec2(at(i), at(i + 1u))));
  } else {
    // Vertex v sits at pixel v * spacing: the nearest one to this pixel.
    uvec2 pix = uvec2(p % pc.width, p / pc.width);
    uvec2 v = min((pix + pc.guide.z / 2u) / max(pc.guide.z, 1u), pc.guide.xy - 1u);
    uint first = ((v.y * pc.guide.x + v.x) * pc.guide.w) * 4u;
    float w = 0.0f, m1 = 0.0f;
    for (uint k = 0u; k < pc.guide.w; ++k) {
      float sw = at(first + 4u * k), sm = at(first + 4u * k + 2u);
      if (sw > 0.0f && sw < 1e30f) {
        w += sw;
        m1 += sm;
      }
    }
    out_value = pack_srgb8(vec3(w > 0.0f ? clamp(m1 / w * pc.scale, 0.0f, 1.0f) : 0.0f));
  }
  display[p] = out_value;
}
