// One invocation per item of a 1D range however long: the host (gpu::Kernel::dispatch_1d) spreads the
// workgroups over x and y, because a dispatch has at most maxComputeWorkGroupCount[0] (65535 on many
// devices) groups along x, and a 3840x2160 frame at 64 per group needs 129600.
#ifndef HAZE_DISPATCH_GLSL
#define HAZE_DISPATCH_GLSL

uint invocation_index() {
  return gl_GlobalInvocationID.y * (gl_NumWorkGroups.x * gl_WorkGroupSize.x) + gl_GlobalInvocationID.x;
}

#endif
