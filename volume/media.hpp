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

// Grids by index, each made once from its source (file and grid name, or procedural spec).
struct GridSet {
  std::vector<vdb::DeviceGrid> grids;
  std::vector<std::string> grid_sources;  // what each grid was made from
  std::vector<std::string>
      grid_labels;  // the scene key that first named it ("media[0].grid"), for the ledger
};

struct DeviceMedia : GridSet {
  // grids: density (and emission) grids, each once; GpuMedium::grid names them by their index.
  std::vector<glsl::GpuMedium> media;
  vdb::MajorantGrid majorant;
  std::vector<std::string> notes;  // clamps and replacements the user should know about
  uint64_t nan_voxels = 0;
};

// Loads or generates every VDB medium of the scene and builds the majorant grid. Grids of `previous` whose
// source is unchanged (an animation moving or scaling a medium) are reused instead of read again.
DeviceMedia build_media(const scene::Scene& s, const DeviceMedia* previous = nullptr);

// The velocity grids of the media of `prev` (the previous frame, whose virtual points they move): x, y, z of
// each medium with a velocity, in media order. Grids of `previous` whose source is unchanged are reused.
struct DeviceVelocity : GridSet {
  std::vector<int32_t> first;  // per medium: index of its x grid (y, z follow), -1 without velocity
  std::vector<std::string> notes;
};
DeviceVelocity build_velocity(const scene::Scene& prev, const DeviceVelocity* previous = nullptr);

// How the VDB media of `s` moved since `prev` (the previous frame): one entry per medium whose transform
// changed or that has a velocity in `velocity` (built from `prev`), for the volume motion vectors of the
// virtual points inside it.
std::vector<glsl::MediumMotion> media_motion(const scene::Scene& s, const scene::Scene& prev,
                                             const DeviceMedia& media, const DeviceVelocity& velocity = {});

// A GridSet on the device: a buffer per grid (a line of its own in the ledger, uploaded again only when its
// source changes) and the table of their device addresses, the binding "grids" of shaders/volume/grids.glsl.
// Each grid may be as large as one allocation (maxMemoryAllocationSize); together they are bounded by the
// device's memory only.
class DeviceGrids {
 public:
  // Holds `set` on the device; an empty set (or !wanted) holds no buffer.
  void update(gpu::Context& ctx, const GridSet& set, bool wanted);
  const gpu::Buffer& table() const { return table_; }
  bool empty() const { return !table_.valid(); }

 private:
  std::vector<gpu::Buffer> buffers_;
  std::vector<std::string> sources_;  // the source each of buffers_ holds
  gpu::Buffer table_;
};

// The media on the device. Features: HAZE_HETERO (VDB media: the grid table, media table, and the majorant
// grid, which the default estimator's scenes hold as HAZE_MINORANT's grid of pairs instead), HAZE_HAZE
// (homogeneous haze, in the scene block only), HAZE_EMISSION (an emitting VDB medium), HAZE_CHROMATIC (some
// medium's sigma_t_color is not [1, 1, 1]: per-channel extinction), and for the default estimator's tracking
// kernel (declare_default_tracking) with one grey VDB medium without emission HAZE_DECOMPOSITION (delta
// tracking's collisions under the control need no lookup), and where no grid value is negative
// HAZE_STOCHASTIC_LOOKUP (one voxel a lookup, chosen by the trilinear weights; HAZE_ONE_GRID keeps the one
// grid's accessor over a sample). Every NanoVDB grid is a buffer of its own, read through its device address
// (DeviceGrids), so the grids together may exceed maxStorageBufferRange. How the media moved since the
// previous frame (transforms and velocity grids) is the volume motion pass's input
// (guiding/volume_motion.hpp), kept only while wanted.
class Media : public gpu::DeviceData {
 public:
  explicit Media(gpu::Context& ctx) : ctx_(ctx) {}

  // Builds the media of `s` (reusing grids of unchanged sources); buffers are reused when their size is
  // unchanged, and absent features hold none.
  void update(const scene::Scene& s);
  // How the media of `s` moved since `prev`, for the volume motion pass; with `velocity` (the pass will
  // project the previous frame's points) the velocity grids of `prev`'s media are loaded too. Without
  // `wanted` nothing is kept.
  void update_motion(const scene::Scene& s, const scene::Scene& prev, bool wanted, bool velocity);

  bool any() const { return hetero_ || haze_; }  // any medium at all
  bool hetero() const { return hetero_; }
  const DeviceMedia& host() const { return host_; }
  const DeviceVelocity& host_velocity() const { return velocity_; }
  // The moved media (glsl::MediumMotion each) and their number; nullptr and 0 when none moved.
  const gpu::Buffer* motion() const { return motion_.valid() ? &motion_ : nullptr; }
  uint32_t moving() const { return moving_; }
  // The velocity grids' table (binding "grids" of the volume motion pass); nullptr when no medium has one.
  const gpu::Buffer* velocity_grids() const {
    return velocity_grids_.empty() ? nullptr : &velocity_grids_.table();
  }
  std::vector<std::string> notes() const;  // the media's and the velocity grids'

  void declare(gpu::KernelDecl& k) const override;
  // For the kernel whose tracking takes the minorant grid's controls: HAZE_DECOMPOSITION where a collision
  // needs only constants, HAZE_STOCHASTIC_LOOKUP where no grid value is negative; nothing unless the scene's
  // estimator is the default one and it has VDB media.
  void declare_default_tracking(gpu::KernelDecl& k) const;
  void bind(gpu::Bindings& b) const override;
  // counts.x, the haze, the majorant grid's bounds and resolution, the tracking step cap.
  void fill(glsl::GpuScene& g) const;

 private:
  gpu::Context& ctx_;
  DeviceMedia host_;
  bool hetero_ = false, haze_ = false, emission_ = false;
  bool chromatic_ = false;  // HAZE_CHROMATIC: some medium's sigma_t_color is not [1, 1, 1]
  float color_max_ = 1.f;   // the largest multiplier over media and channels
  float color_min_ = 1.f;   // the smallest over the VDB media's channels
  std::optional<scene::Haze> haze_params_;
  DeviceVelocity velocity_;
  DeviceGrids grids_, velocity_grids_;
  gpu::Buffer table_, majorant_, minorant_, motion_;
  uint32_t moving_ = 0;
};

}  // namespace haze::volume
