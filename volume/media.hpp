// The scene's participating media: the host-side medium model (density scale, albedo, phase, emission;
// docs/rendering.md) packed for the shaders, and the device part that owns their buffers (NanoVDB grids,
// media table, majorant grid) and says which medium features a kernel needs.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "gpu/gpu.hpp"
#include "gpu/kernel.hpp"
#include "scene/scene.hpp"
#include "shaders/glsl.hpp"
#include "vdb/vdb.h"

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

// How the VDB media of `s` moved since `prev` (the previous frame): one entry per medium whose transform
// changed, for the volume motion vectors of the virtual points inside it.
std::vector<glsl::MediumMotion> media_motion(const scene::Scene& s, const scene::Scene& prev,
                                             const DeviceMedia& media);

// The media on the device. Features: HAZE_HETERO (VDB media: NanoVDB grids, media table, majorant grid),
// HAZE_HAZE (homogeneous haze, in the scene block only), HAZE_EMISSION (an emitting VDB medium).
class Media : public gpu::DeviceData {
 public:
  explicit Media(gpu::Context& ctx) : ctx_(ctx) {}

  // Builds the media of `s` (reusing grids of unchanged sources) and how they moved since `prev`; buffers
  // are reused when their size is unchanged, and absent features hold none.
  void update(const scene::Scene& s, const scene::Scene& prev);

  bool any() const { return hetero_ || haze_; }  // any medium at all
  bool hetero() const { return hetero_; }
  const DeviceMedia& host() const { return host_; }
  // The moved media (glsl::MediumMotion each) and their number; nullptr and 0 when none moved.
  const gpu::Buffer* motion() const { return motion_.valid() ? &motion_ : nullptr; }
  uint32_t moving() const { return moving_; }

  void declare(gpu::KernelDecl& k) const override;
  void bind(gpu::Bindings& b) const override;
  // counts.x, the haze, the majorant grid's bounds and resolution, the tracking step cap.
  void fill(glsl::GpuScene& g) const;

 private:
  gpu::Context& ctx_;
  DeviceMedia host_;
  bool hetero_ = false, haze_ = false, emission_ = false;
  std::optional<scene::Haze> haze_params_;
  gpu::Buffer nanovdb_, table_, majorant_, motion_;
  uint32_t moving_ = 0;
};

}  // namespace haze::volume
