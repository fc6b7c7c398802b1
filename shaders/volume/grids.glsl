// NanoVDB grids on the device (volume/media.hpp): every grid is a buffer of its own, read by PNanoVDB
// through its device address (GL_EXT_buffer_reference), so neither one grid nor all of them together are
// bounded by maxStorageBufferRange (128 MiB on lavapipe); one allocation (maxMemoryAllocationSize) bounds
// each grid. The binding "grids" holds each grid's address; a grid is named by its index there.
#ifndef HAZE_GRIDS_GLSL
#define HAZE_GRIDS_GLSL

#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer NanoVdbWords {
  uint words[];
};
layout(std430, binding = BINDING_grids) readonly buffer GridTable {
  uvec2 grid_addresses[];  // device address of grid i (lo, hi)
};

// PNanoVDB's buffer is the grid's buffer reference; its addresses stay 32-bit byte offsets within a grid.
#define PNANOVDB_GLSL
#define PNANOVDB_BUF_CUSTOM
#define pnanovdb_buf_t NanoVdbWords
uint pnanovdb_buf_read_uint32(pnanovdb_buf_t buf, uint byte_offset) {
  return buf.words[byte_offset >> 2u];
}
uvec2 pnanovdb_buf_read_uint64(pnanovdb_buf_t buf, uint byte_offset) {
  return uvec2(buf.words[byte_offset >> 2u], buf.words[(byte_offset >> 2u) + 1u]);
}
#define pnanovdb_grid_type_t uint
#define PNANOVDB_GRID_TYPE_GET(grid_typeIn, nameIn) pnanovdb_grid_type_constants[grid_typeIn].nameIn
#include "nanovdb/PNanoVDB.h"

// A new accessor of grid, at its root.
pnanovdb_readaccessor_t grid_accessor(uint grid) {
  pnanovdb_buf_t buf = pnanovdb_buf_t(grid_addresses[grid]);
  pnanovdb_grid_handle_t handle;
  handle.address.byte_offset = 0u;
  pnanovdb_readaccessor_t acc;
  pnanovdb_readaccessor_init(acc, pnanovdb_tree_get_root(buf, pnanovdb_grid_get_tree(buf, handle)));
  return acc;
}

// Trilinear value of float grid `grid` at an index-space position: one PNanoVDB lookup call site, corners
// in a loop that is kept rolled (each inlined lookup costs about a second of pipeline creation on
// lavapipe). Call it from one place per kernel.
float grid_trilinear(uint grid, vec3 p) {
  pnanovdb_buf_t buf = pnanovdb_buf_t(grid_addresses[grid]);
  pnanovdb_readaccessor_t acc = grid_accessor(grid);
  vec3 pf = floor(p);
  ivec3 i0 = ivec3(pf);
  vec3 f = p - pf;
  float sum = 0.0f;
  [[dont_unroll]] for (int c = 0; c < 8; ++c) {
    ivec3 o = ivec3(c & 1, (c >> 1) & 1, c >> 2);
    vec3 w3 = mix(vec3(1.0f) - f, f, vec3(o));
    ivec3 ijk = i0 + o;
    pnanovdb_address_t a = pnanovdb_readaccessor_get_value_address(PNANOVDB_GRID_TYPE_FLOAT, buf, acc, ijk);
    sum += w3.x * w3.y * w3.z * pnanovdb_read_float(buf, a);
  }
  return sum;
}

#if HAZE_STOCHASTIC_LOOKUP
#include "common/sampling.glsl"
// One voxel of grid's trilinear footprint at p, chosen with probability equal to its weight
// (trilinear_corner, uniform u): an unbiased estimate of grid_trilinear at one read, where the caller uses
// the value linearly (the trackers do) and no value is negative (the host checks). acc: the grid's accessor,
// kept by the caller (the next lookup often falls in the same leaf).
float grid_voxel(uint grid, vec3 p, float u, INOUT(pnanovdb_readaccessor_t) acc) {
  pnanovdb_buf_t buf = pnanovdb_buf_t(grid_addresses[grid]);
  vec3 pf = floor(p);
  ivec3 ijk = ivec3(pf) + trilinear_corner(p - pf, u);
  return pnanovdb_read_float(
      buf, pnanovdb_readaccessor_get_value_address(PNANOVDB_GRID_TYPE_FLOAT, buf, acc, ijk));
}
#endif

#endif
