#version 460
// gpu_test: c[i] = a[i] + b[i] + push.k (+ EXTRA, a specialization constant, 0 by default).
layout(local_size_x = 64) in;
layout(constant_id = 0) const uint EXTRA = 0;
layout(std430, set = 0, binding = 0) readonly buffer A { float a[]; };
layout(std430, set = 0, binding = 1) readonly buffer B { float b[]; };
layout(std430, set = 0, binding = 2) writeonly buffer C { float c[]; };
layout(push_constant) uniform Push {
  uint n;
  float k;
} push;

void main() {
  uint i = gl_GlobalInvocationID.x;
  if (i >= push.n) return;
  c[i] = a[i] + b[i] + push.k + float(EXTRA);
}
