#version 460
// Per-pixel means of the accumulated sums, the sample variance of the final radiance, the virtual point
// depth, and the tonemapped 8-bit preview.
#extension GL_GOOGLE_include_directive : require
layout(local_size_x = 64) in;
#include "common/color.glsl"
#include "common/compat.glsl"
#include "common/dispatch.glsl"
#include "volume/gpu_scene.glsl"

PIXEL_LAYER_IN(acc_l);
PIXEL_LAYER_IN(acc_l2);
PIXEL_LAYER_IN(acc_vol);
PIXEL_LAYER_IN(acc_surf);
PIXEL_LAYER_IN(acc_demod);
PIXEL_LAYER_IN(acc_demod2);
PIXEL_LAYER_IN(acc_vp);
#ifdef BINDING_acc_emit
PIXEL_LAYER_IN(acc_emit);
PIXEL_LAYER_OUT(out_emit);
#endif
PIXEL_LAYER_OUT(out_l);
PIXEL_LAYER_OUT(out_vol);
PIXEL_LAYER_OUT(out_surf);
PIXEL_LAYER_OUT(out_var);
PIXEL_LAYER_OUT(out_demod);
PIXEL_LAYER_OUT(out_demod_m2);
layout(std430, binding = BINDING_ldr) writeonly buffer LdrBuffer {
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
  uint p = invocation_index();
  if (p >= pc.pixels) return;
  vec4 l = acc_l[p], l2 = acc_l2[p], vol = acc_vol[p], surf = acc_surf[p], vp = acc_vp[p];
  // Samples dropped for a non-finite radiance are not samples of the pixel (counted in stats.json).
  float kept = float(pc.samples) - surf.w;
  float n = max(kept, 1.0f);
  vec3 mean = l.rgb / n;
  vec3 m2 = l2.rgb / n;
  vec3 var = kept > 1.0f ? max(m2 - mean * mean, vec3(0.0f)) * (n / (n - 1.0f)) : vec3(0.0f);

  // Virtual point depth: where the volume contribution concentrates, else the guide's mean, else the depth.
  float depth = vol.w / n;
  float vp_depth = depth;
  if (vp.y > 0.0f)
    vp_depth = vp.x / vp.y;
  else if (vp.w > 0.0f)
    vp_depth = vp.z / vp.w;

  out_l[p] = vec4(mean, depth);
  out_vol[p] = vec4(vol.rgb / n, vp_depth);
  out_surf[p] = vec4(surf.rgb / n, l.w / n);
  out_var[p] = vec4(var, 0.0f);
  out_demod[p] = vec4(acc_demod[p].rgb / n, 0.0f);
  out_demod_m2[p] = vec4(acc_demod2[p].rgb / n, 0.0f);
#ifdef BINDING_acc_emit
  out_emit[p] = vec4(acc_emit[p].rgb / n, 0.0f);
#endif
  ldr[p] = pack_srgb8(tonemap(mean * pc.exposure_scale, pc.tonemap));
}
