// haze::vdb: reading .vdb files, grid checks, conversion to NanoVDB, majorant grids and procedural volumes.
// This header stays free of OpenVDB (its translation units compile slowly); OpenVDB lives in openvdb_io.cpp.
#pragma once

#include <cstdint>
#include <glm/glm.hpp>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace haze::vdb {

// One-line message that names the file (and grid) and says what to do.
struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct GridInfo {
  std::string name, type;  // type: "float", "half" (float saved as half), "double", "vec3s", "int32", ...
  std::string grid_class;  // "fog volume", "level set", "unknown", ...
  glm::ivec3 index_min{0}, index_max{0};  // active voxel bbox (inclusive); all 0 for an empty grid
  glm::dvec3 world_min{0}, world_max{0};  // world bbox of the centres of that index bbox
  glm::dvec3 voxel_size{0};
  uint64_t active_voxels = 0;
  double value_min = 0, value_max = 0;  // over active values (scalar grids only, else 0)
  uint64_t memory_bytes = 0;            // OpenVDB's in-memory size of the grid
  bool affine = true;                   // false for frustum (non-linear) transforms
};
// All grids of a .vdb file (reads them fully: value ranges need the voxels).
std::vector<GridInfo> inspect(const std::string& path);
nlohmann::json to_json(const GridInfo&);
nlohmann::json to_json(const std::vector<GridInfo>&);

// A scalar grid converted for the device: NanoVDB float grid, its transform honoured.
struct DeviceGrid {
  std::string name;
  std::vector<uint8_t> nanovdb;  // whole NanoVDB grid buffer (size multiple of 32), upload as-is for PNanoVDB
  glm::dmat4 index_to_world{1};  // world = M * (i,j,k,1); integer index coords are voxel centres
  glm::ivec3 index_min{0}, index_max{0};               // active bbox (inclusive)
  float value_min = 0, value_max = 0, background = 0;  // value range over active values
  uint64_t active_voxels = 0;
  uint64_t nan_voxels = 0;  // NaN/Inf values found and replaced by 0 (NanPolicy::Zero)
};

enum class NanPolicy { Zero, Error };

// Reads grid `grid_name` from a .vdb file and converts it. Throws Error for: missing file, not a VDB file or
// corrupt, no grid with that name (lists the names present), grid not scalar float/half (says its type),
// non-affine transform, empty grid, NaN/Inf values with NanPolicy::Error. Half grids load as float.
// NaN/Inf anywhere in the tree (active or not, voxels, tiles, background) become 0 under NanPolicy::Zero.
// `key` is the scene key that names the grid ("media[0].grid"), for the message.
DeviceGrid load_grid(const std::string& path, const std::string& grid_name, NanPolicy nan = NanPolicy::Zero,
                     const std::string& key = "");
// The check load_grid starts with, reading only the file's header: before the device starts.
void check_grid_name(const std::string& path, const std::string& grid_name, const std::string& key);

// A velocity field as three float grids, one per component, each with its own index transform (a staggered
// grid's x component sits half a voxel lower in x than the voxel centre, and likewise for y and z).
struct VelocityGrids {
  DeviceGrid c[3];
  std::string layout;  // "vec3s", "vec3s staggered" or "float x/y/z" (which grids the file held)
  uint64_t nan_voxels = 0;
};
// Reads the velocity `grid_name` of a .vdb file: a vec3s grid of that name (a staggered one honoured), else
// the float grids grid_name.x, .y, .z (each with its own transform). NaN/Inf components become 0 (counted in
// nan_voxels). Throws Error naming `key` ("media[0].velocity.grid") and the grids present when neither is
// there, for a vector grid of another type, a non-affine transform or an empty grid.
VelocityGrids load_velocity(const std::string& path, const std::string& grid_name, const std::string& key);
// The name check load_velocity starts with, from the file's header.
void check_velocity_name(const std::string& path, const std::string& grid_name, const std::string& key);

// Procedural volumes built with OpenVDB's tools. Voxel centres sit at integer multiples of voxel_size.
struct ProceduralSpec {
  std::string kind = "box";  // "box" | "sphere" | "cloud" | "height_fog" | "ramp" (linear in y)
  double voxel_size = 0.05;  // world units
  glm::dvec3 center{0};
  glm::dvec3 size{2};  // world extent (box/height_fog: full size; sphere/cloud: diameter in size.x)
  double density =
      1.0;  // value inside (box, sphere), peak (cloud), at the base y = center.y - size.y/2 (height_fog)
  double falloff = 0.3;    // height_fog: scale height (world units); cloud: noise amplitude (0..1)
  double frequency = 2.0;  // cloud noise frequency (per world unit)
  uint32_t seed = 1;       // cloud noise seed
  int octaves = 4;         // cloud noise octaves
};
// Parses and validates; missing keys keep their defaults. `size` is a number or [x,y,z], `center` [x,y,z].
// Unknown key or bad value -> Error starting with `where` and naming the key.
ProceduralSpec procedural_from_json(const nlohmann::json& j, const std::string& where);
nlohmann::json to_json(const ProceduralSpec&);
// Checks ranges (also done by procedural_from_json); `where` prefixes the message.
void validate(const ProceduralSpec& spec, const std::string& where);

// Analytic value of the procedural field at a world position (what the voxels sample, before
// voxelization; the sphere's sdfToFogVolume ramp and the box's voxel snapping are not modelled).
// For tests and CPU references.
double procedural_value(const ProceduralSpec& spec, glm::dvec3 world);

DeviceGrid make_procedural(const ProceduralSpec& spec);  // grid name "density"
// What write_procedural adds to the density: a translation of the grid (its transform; the voxels stay),
// and a constant velocity written as float grids vel.x, vel.y, vel.z over the density's active box
// dilated by two voxels (so that trilinear lookups anywhere in the density's support, and one voxel beyond,
// read exactly this velocity).
struct ProceduralExtras {
  glm::dvec3 offset{0};                // world units
  std::optional<glm::dvec3> velocity;  // world units per whatever the scene's velocity.unit says
};
// Writes a .vdb with one float fog-volume grid "density" and the extras (to a temporary file, then renamed).
void write_procedural(const ProceduralSpec& spec, const std::string& out_path,
                      const ProceduralExtras& extras = {});
// The same volume, built once, written to several files (a sequence), each with its own offset.
struct ProceduralFile {
  std::string path;
  glm::dvec3 offset{0};
};
void write_procedural(const ProceduralSpec& spec, const std::vector<ProceduralFile>& files,
                      std::optional<glm::dvec3> velocity);

// A scalar grid given voxel by voxel (for scripted inputs and tests): float, or half (float stored as half).
// Voxels not listed hold the background. (No vector types: each grid type costs 12 s of compile time.)
struct VoxelGrid {
  std::string name = "density";
  std::string type = "float";
  bool fog_volume = false;       // grid class "fog volume" (else "unknown")
  glm::dmat4 index_to_world{1};  // affine; world = M * (i,j,k,1)
  float background = 0;
  std::vector<std::pair<glm::ivec3, float>> voxels;
  // Boxes of active voxels with one value (inclusive index bounds), filled before `voxels` are set.
  struct Box {
    glm::ivec3 lo, hi;
    float value;
  };
  std::vector<Box> boxes;
};
// Writes the grids to one .vdb file (to a temporary file, read back, then renamed).
void write_grids(const std::vector<VoxelGrid>& grids, const std::string& out_path);

// World-space majorant and minorant grid over several media. Conservative for trilinear interpolation at
// voxel centres: each cell holds >= scale * max (<= scale * min) of every voxel (active or not) whose
// trilinear support (+-1 voxel) overlaps the cell, summed over media; the min takes the background where
// the tree has no node, counts negative values as 0, and counts a medium only in cells inside its box. Each
// medium is taken to be zero outside its index bbox dilated by one voxel and outside its clip box (the
// renderer clips media to both). Values carry a 1e-5 relative margin for float rounding.
struct MajorantInput {
  const DeviceGrid* grid;
  glm::dmat4 object_to_world;
  double density_scale;
  // World box the medium is clipped to (zero outside); default unbounded.
  glm::dvec3 clip_min{-1e300}, clip_max{1e300};
};
struct MajorantGrid {
  glm::ivec3 res{0};
  glm::vec3 world_min{0},
      world_max{0};               // union of the media's world bboxes (index bbox dilated by one voxel)
  std::vector<float> sigma_max;   // res.x*res.y*res.z, x fastest
  std::vector<float> sigma_min;   // the same cells' minorant (the control of decomposition tracking)
  std::vector<float> sigma_mean;  // their mean density, within [min, max] (the control of ratio tracking)
  // Per input medium, the smallest value its sampler can read in its box (+inf for a medium of scale 0):
  // where none is negative, one voxel chosen by the trilinear weights estimates the density without bias.
  std::vector<float> value_min;
  glm::vec3 cell_size() const { return (world_max - world_min) / glm::vec3(glm::max(res, glm::ivec3(1))); }
  float at(glm::ivec3 c) const { return sigma_max[(size_t(c.z) * res.y + c.y) * res.x + c.x]; }
  float min_at(glm::ivec3 c) const { return sigma_min[(size_t(c.z) * res.y + c.y) * res.x + c.x]; }
};
// `resolution` = cells along the longest axis (others proportional, >= 1; cells need not be cubes).
// Empty input -> res 0. Throws Error for resolution < 1 or a negative/non-finite density_scale.
MajorantGrid build_majorant(const std::vector<MajorantInput>& media, int resolution);

// CPU reference density: NanoVDB's trilinear sampler (nanovdb::SampleFromVoxels<..,1>) at an index-space
// position; background outside the tree. One-off calls copy the buffer to 32-byte-aligned memory; use
// Sampler for many lookups.
float sample_index_trilinear(const DeviceGrid& g, glm::dvec3 index_pos);

// Holds a 32-byte-aligned copy of the NanoVDB buffer (NanoVDB types are alignas(32)).
class Sampler {
 public:
  explicit Sampler(const DeviceGrid& g);
  float trilinear(glm::dvec3 index_pos) const;               // same as sample_index_trilinear
  float voxel(glm::ivec3 ijk) const;                         // value at a voxel (active or not)
  const void* aligned_buffer() const { return buf_.get(); }  // the NanoVDB grid, 32-byte aligned
  glm::dmat4 world_to_index;                                 // inverse of the grid's index_to_world

 private:
  struct Aligned {
    alignas(32) unsigned char bytes[32];
  };
  std::unique_ptr<Aligned[]> buf_;
};

}  // namespace haze::vdb
