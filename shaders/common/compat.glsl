// Lets the pure-function headers in shaders/common compile both as GLSL and, with GLM, as C++ (CPU tests
// call the same code the shaders run). Include this first.
#ifndef HAZE_COMPAT_GLSL
#define HAZE_COMPAT_GLSL

#ifdef __cplusplus
#define INOUT(T) T&
#define OUT(T) T&
#define HAZE_INLINE inline
#else
#define INOUT(T) inout T
#define OUT(T) out T
#define HAZE_INLINE
#endif

const float PI = 3.14159265358979323846;
const float INV_PI = 0.31830988618379067154;
const float INV_4PI = 0.07957747154594766788;
// Stand-in for an unbounded distance; finite so that 0 * T_INF stays 0.
const float T_INF = 1e30;

#endif
