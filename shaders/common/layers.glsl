// Per-pixel vec4 layers (gpu/pixel_layers.hpp): each layer is its own storage buffer, bound under its own
// name, so that no buffer of a frame outgrows maxStorageBufferRange.
#ifndef HAZE_LAYERS_GLSL
#define HAZE_LAYERS_GLSL

#ifndef __cplusplus
// PIXEL_LAYER(acc_l) declares vec4 acc_l[] at binding BINDING_acc_l (read-write); PIXEL_LAYER_IN and
// PIXEL_LAYER_OUT declare it read-only and write-only.
#define PIXEL_LAYER(name)                                        \
  layout(std430, binding = BINDING_##name) buffer Layer_##name { \
    vec4 name[];                                                 \
  }
#define PIXEL_LAYER_IN(name)                                              \
  layout(std430, binding = BINDING_##name) readonly buffer Layer_##name { \
    vec4 name[];                                                          \
  }
#define PIXEL_LAYER_OUT(name)                                              \
  layout(std430, binding = BINDING_##name) writeonly buffer Layer_##name { \
    vec4 name[];                                                           \
  }
#endif

#endif
