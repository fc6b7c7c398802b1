#pragma once
// The table of GLSL sources compiled into the binary, written at build time by cmake/EmbedShaders.cmake
// (library haze_shader_sources). Read it through gpu::ShaderSources::embedded().

#include <cstddef>

namespace haze::gpu::embedded {

struct File {
  const char* path;           // relative to the shader root: "volume/trace.comp", "nanovdb/PNanoVDB.h"
  const char* const* pieces;  // the text, in order, split into literals of < 64 KiB
  size_t piece_count;
  size_t size;  // bytes in all pieces together
};

extern const File kFiles[];
extern const size_t kFileCount;

}  // namespace haze::gpu::embedded
