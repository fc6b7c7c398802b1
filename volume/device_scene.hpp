// The scene as the shaders see it: media packed for PNanoVDB, the majorant grid, the light list and the
// GpuScene block. Host-side medium model (DESIGN.md section 3).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "scene/scene.hpp"
#include "vdb/vdb.h"
#include "volume/features.hpp"
#include "volume/glsl.hpp"

namespace haze::volume {

// HG g is kept away from +-1, where the phase function becomes a delta the sampler cannot represent.
constexpr float kMaxAbsG = 0.99f;
// Upper bound on tracking steps per query: a pathological majorant cannot hang a dispatch.
constexpr uint32_t kMaxTrackingSteps = 1u << 20;

struct DeviceMedia {
  std::vector<vdb::DeviceGrid> grids;     // density (and emission) grids, in upload order
  std::vector<std::string> grid_sources;  // what each grid was made from (file and grid, or procedural spec)
  std::vector<uint32_t> nanovdb;          // all grids, each at a 32-byte aligned offset
  std::vector<glsl::GpuMedium> media;
  vdb::MajorantGrid majorant;
  std::vector<std::string> notes;  // clamps and replacements the user should know about
  uint64_t nan_voxels = 0;
};

// Loads or generates every VDB medium of the scene and builds the majorant grid. Grids of `previous` whose
// source is unchanged (an animation moving or scaling a medium) are reused instead of read again.
DeviceMedia build_media(const scene::Scene& s, const DeviceMedia* previous = nullptr);

// Local lights first (equi-angular sampling walks the first counts.z entries), then sun, then environment.
std::vector<glsl::GpuLight> build_lights(const scene::Scene& s);

// The camera as the shaders use it (shaders/common/camera.glsl): right and up scaled by the field of view.
struct CameraBasis {
  glm::vec4 position, right, up, forward;
};
CameraBasis camera_basis(const scene::Camera& c, const scene::RenderSettings& r);

// `frame` decorrelates the random numbers of animation frames (frame 0 uses the seed as it is);
// `prev_camera` (default: the same camera) is the previous frame's, for motion vectors.
glsl::GpuScene build_gpu_scene(const scene::Scene& s, const DeviceMedia& media, size_t num_lights,
                               size_t num_local_lights, uint32_t frame = 0,
                               const scene::Camera* prev_camera = nullptr);

}  // namespace haze::volume
