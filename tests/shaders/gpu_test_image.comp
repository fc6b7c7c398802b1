#version 460
// gpu_test: dst(x, y) = src(x, y) * w[x] + (x, y, push.bias, 1), images read and written per texel.
layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D src;
layout(std430, set = 0, binding = 1) readonly buffer W {
  float w[];
};
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D dst;
layout(push_constant) uniform Push {
  uvec2 size;
  float bias;
}
push;

void main() {
  uvec2 p = gl_GlobalInvocationID.xy;
  if (any(greaterThanEqual(p, push.size))) return;
  vec4 v = imageLoad(src, ivec2(p));
  imageStore(dst, ivec2(p), v * w[p.x] + vec4(p.x, p.y, push.bias, 1.0));
}
