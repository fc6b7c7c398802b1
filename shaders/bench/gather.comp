#version 460
// The loads of one subsampled SVGF filter iteration without its math (haze bench --only svgf): per pixel
// the centre and the six taps of iteration 0 ((+-2, 0) and the four diagonals) read as 16-byte records
// (the filter's colour and packed geometry: half rgb and sigma, f32 depth, snorm16 octahedral normal) from a
// storage buffer, decoded as the filter decodes them and summed, then written as one half-float word.
// Taps past the border are clamped to it, so that no lane is masked off and the figure is the loads alone.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 8, local_size_y = 8) in;
layout(std430, binding = BINDING_records) readonly buffer Records {
  uvec4 records[];
};
layout(std430, binding = BINDING_sums) writeonly buffer Sums {
  uvec2 sums[];
};
layout(push_constant) uniform Push {
  uint width, height;
}
pc;

const ivec2 TAPS[7] =
    ivec2[7](ivec2(0, 0), ivec2(2, 0), ivec2(-2, 0), ivec2(1, 1), ivec2(-1, 1), ivec2(1, -1), ivec2(-1, -1));

void main() {
  ivec2 pix = ivec2(gl_GlobalInvocationID.xy);
  if (pix.x >= int(pc.width) || pix.y >= int(pc.height)) return;
  vec4 s = vec4(0.0f);
  for (int k = 0; k < 7; ++k) {
    ivec2 q = clamp(pix + TAPS[k], ivec2(0), ivec2(pc.width - 1u, pc.height - 1u));
    uvec4 r = records[uint(q.y) * pc.width + uint(q.x)];
    vec2 n = unpackSnorm2x16(r.w);
    s += vec4(unpackHalf2x16(r.x), unpackHalf2x16(r.y)) + vec4(uintBitsToFloat(r.z), n, 0.0f);
  }
  sums[uint(pix.y) * pc.width + uint(pix.x)] = uvec2(packHalf2x16(s.xy), packHalf2x16(s.zw));
}
