// Everything that includes OpenVDB (slow to compile: keep it in this one translation unit).
#include <fmt/format.h>
#include <nanovdb/util/OpenToNanoVDB.h>
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/ChangeBackground.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <mutex>

#include "vdb/alloc_budget.hpp"
#include "vdb/vdb.h"

namespace haze::vdb {
namespace fs = std::filesystem;
namespace {

void init_openvdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

// Library messages can span lines; ours are one line.
std::string one_line(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  return s;
}

std::string type_name(const openvdb::GridBase& g) {
  std::string t = g.valueType();
  // OpenVDB 10 has no half grid type: "half" is a float grid stored as half in the file.
  if (t == "float" && g.saveFloatAsHalf()) return "half";
  return t;
}

// OpenVDB's Mat4 multiplies row vectors (p' = p * M) and glm column vectors (p' = M * p); with glm's
// m[col][row] indexing the element copy is the identity.
glm::dmat4 to_glm(const openvdb::math::Mat4d& m) {
  glm::dmat4 r;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) r[i][j] = m(i, j);
  return r;
}

void world_bbox(const openvdb::math::Transform& xf, const openvdb::CoordBBox& b, glm::dvec3& lo,
                glm::dvec3& hi) {
  lo = glm::dvec3(std::numeric_limits<double>::max());
  hi = -lo;
  for (int c = 0; c < 8; ++c) {
    openvdb::Vec3d p((c & 1 ? b.max() : b.min()).x(), (c & 2 ? b.max() : b.min()).y(),
                     (c & 4 ? b.max() : b.min()).z());
    openvdb::Vec3d w = xf.indexToWorld(p);
    lo = glm::min(lo, glm::dvec3(w.x(), w.y(), w.z()));
    hi = glm::max(hi, glm::dvec3(w.x(), w.y(), w.z()));
  }
}

// What reading `path` may allocate: no single block beyond the file's size (and 64 MiB), and in all no more
// than 64 times the file (and 256 MiB): a .vdb's in-memory grids are a few times its compressed size.
struct ReadBudget {
  uint64_t file_bytes;
  AllocationBudget budget;
  explicit ReadBudget(uint64_t bytes)
      : file_bytes(bytes), budget(std::max<uint64_t>(64ull << 20, 2 * bytes), (256ull << 20) + 64 * bytes) {}
};

// The one-line error for a read that the budget stopped.
Error over_budget(const std::string& path, const ReadBudget& b) {
  if (!b.budget.total_reached())
    return Error(
        fmt::format("{}: corrupt .vdb: reading it asked for {} bytes at once, more than a file of {} bytes "
                    "can need; re-export it",
                    path, b.budget.refused(), b.file_bytes));
  return Error(
      fmt::format("{}: corrupt .vdb: reading it asked for more than {} bytes in all, far more than a file "
                  "of {} bytes can need; re-export it",
                  path, b.budget.total(), b.file_bytes));
}

uint64_t file_size(const std::string& path) {
  std::error_code ec;
  const auto n = fs::file_size(path, ec);
  return ec ? 0 : uint64_t(n);
}

std::unique_ptr<openvdb::io::File> open_file(const std::string& path) {
  init_openvdb();
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(fmt::format("{}: file not found; check the path", path));
  if (!fs::is_regular_file(path, ec))
    throw Error(fmt::format("{}: not a regular file; give a .vdb file", path));
  auto file = std::make_unique<openvdb::io::File>(path);
  ReadBudget budget(file_size(path));
  try {
    file->open(/*delayLoad=*/false);  // no memory mapping: the file may be replaced while we hold grids
  } catch (const std::bad_alloc&) {
    throw over_budget(path, budget);
  } catch (const std::exception& e) {
    throw Error(fmt::format("{}: not a readable VDB file ({}); check that it is an OpenVDB .vdb file", path,
                            one_line(e.what())));
  }
  return file;
}

std::vector<std::string> grid_names(const openvdb::io::File& file) {
  std::vector<std::string> names;
  for (auto it = file.beginName(); it != file.endName(); ++it) names.push_back(*it);
  return names;
}

// Replaces NaN/Inf everywhere the sampler can read (voxels active or not, tiles, background); returns the
// number of voxels affected (a tile counts all the voxels it covers).
uint64_t scrub_non_finite(openvdb::FloatTree& tree, bool replace) {
  uint64_t bad = 0;
  for (auto leaf = tree.beginLeaf(); leaf; ++leaf) {
    float* v = leaf->buffer().data();
    for (openvdb::Index i = 0; i < openvdb::FloatTree::LeafNodeType::SIZE; ++i)
      if (!std::isfinite(v[i])) {
        ++bad;
        if (replace) v[i] = 0.f;
      }
  }
  auto tile = tree.beginValueAll();
  tile.setMaxDepth(tree.treeDepth() - 2);  // tiles only: leaves were done above
  for (; tile; ++tile)
    if (!std::isfinite(*tile)) {
      bad += tile.getVoxelCount();
      if (replace) tile.setValue(0.f);
    }
  if (!std::isfinite(tree.background())) {
    ++bad;
    if (replace) openvdb::tools::changeBackground(tree, 0.f);
  }
  return bad;
}

DeviceGrid to_device(openvdb::FloatGrid& grid, const std::string& where, NanPolicy nan) {
  const std::string name = grid.getName();
  if (!grid.transform().isLinear())
    throw Error(
        fmt::format("{}: grid '{}' has a non-affine (frustum) transform; resample it to a linear transform",
                    where, name));
  uint64_t bad = scrub_non_finite(grid.tree(), nan == NanPolicy::Zero);
  if (bad && nan == NanPolicy::Error)
    throw Error(
        fmt::format("{}: grid '{}' has {} NaN/Inf voxel values; fix the file or use the NaN policy 'zero' "
                    "to replace them by 0",
                    where, name, bad));
  if (grid.activeVoxelCount() == 0)
    throw Error(
        fmt::format("{}: grid '{}' is empty (no active voxels); pick a grid that holds values", where, name));

  DeviceGrid d;
  d.name = name;
  d.nan_voxels = bad;
  d.active_voxels = grid.activeVoxelCount();
  d.index_to_world = to_glm(grid.transform().baseMap()->getAffineMap()->getMat4());
  openvdb::CoordBBox b = grid.evalActiveVoxelBoundingBox();
  d.index_min = {b.min().x(), b.min().y(), b.min().z()};
  d.index_max = {b.max().x(), b.max().y(), b.max().z()};
  d.background = grid.background();

  auto handle = nanovdb::openToNanoVDB(grid);  // StatsMode::Default computes min/max for value_min/max
  const auto* ng = handle.grid<float>();
  if (!ng)
    throw Error(fmt::format("{}: grid '{}': NanoVDB conversion failed; report this file", where, name));
  d.value_min = ng->tree().root().minimum();
  d.value_max = ng->tree().root().maximum();
  d.nanovdb.assign(handle.data(), handle.data() + handle.size());
  return d;
}

openvdb::CoordBBox centres_inside(glm::dvec3 lo, glm::dvec3 hi, double vs) {
  // Voxel centres i * vs within [lo, hi]; the epsilon keeps centres that sit on the boundary.
  auto c = [&](double x, bool up) {
    double t = x / vs;
    return int(up ? std::ceil(t - 1e-9) : std::floor(t + 1e-9));
  };
  return openvdb::CoordBBox(openvdb::Coord(c(lo.x, true), c(lo.y, true), c(lo.z, true)),
                            openvdb::Coord(c(hi.x, false), c(hi.y, false), c(hi.z, false)));
}

openvdb::FloatGrid::Ptr build_procedural(const ProceduralSpec& s) {
  init_openvdb();
  validate(s, "procedural volume");
  const double vs = s.voxel_size;
  openvdb::FloatGrid::Ptr grid;
  if (s.kind == "sphere") {
    // Narrow-band level set turned into fog: 1 inside, ramping to 0 over the 3 voxels inside the surface.
    grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
        float(s.size.x * 0.5), openvdb::Vec3f(float(s.center.x), float(s.center.y), float(s.center.z)),
        float(vs), 3.f);
    openvdb::tools::sdfToFogVolume(*grid);
    const float k = float(s.density);
    for (auto it = grid->beginValueOn(); it; ++it) it.setValue(*it * k);  // a narrow band: serial is enough
  } else {
    grid = openvdb::FloatGrid::create(0.f);
    grid->setTransform(openvdb::math::Transform::createLinearTransform(vs));
    if (s.kind == "box") {
      openvdb::CoordBBox b = centres_inside(s.center - s.size * 0.5, s.center + s.size * 0.5, vs);
      if (b.empty()) throw Error("procedural volume: box contains no voxel centre; lower voxel_size");
      grid->fill(b, float(s.density), true);  // sparse fill: constant 8^3 and larger blocks become tiles
    } else {
      glm::dvec3 h = s.kind == "cloud" ? glm::dvec3(s.size.x * 0.5 * (1 + s.falloff)) : s.size * 0.5;
      openvdb::CoordBBox b = centres_inside(s.center - h, s.center + h, vs);
      b.expand(1);
      openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(b, 0.f);
      tbb::parallel_for(tbb::blocked_range<int>(b.min().x(), b.max().x() + 1),
                        [&](const tbb::blocked_range<int>& r) {
                          for (int x = r.begin(); x < r.end(); ++x)
                            for (int y = b.min().y(); y <= b.max().y(); ++y)
                              for (int z = b.min().z(); z <= b.max().z(); ++z)
                                dense.setValue(openvdb::Coord(x, y, z),
                                               float(procedural_value(s, glm::dvec3(x, y, z) * vs)));
                        });
      openvdb::tools::copyFromDense(dense, *grid, 0.f);  // zeros (the background) stay inactive
    }
  }
  grid->setName("density");
  grid->setGridClass(openvdb::GRID_FOG_VOLUME);
  return grid;
}

// The range of a tree's active values (voxels and tiles), serially: tools::minMax instantiates TBB's
// reductions for each numeric grid type (a ninth of this file's object code) for a command that reads one
// file.
template <typename TreeT>
std::pair<double, double> active_range(const TreeT& tree) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (auto it = tree.cbeginValueOn(); it; ++it) {
    lo = std::min(lo, double(*it));
    hi = std::max(hi, double(*it));
  }
  return {lo, hi};
}

}  // namespace

std::vector<GridInfo> inspect(const std::string& path) {
  auto file = open_file(path);
  openvdb::GridPtrVecPtr grids;
  try {
    ReadBudget budget(file_size(path));
    try {
      grids = file->getGrids();
    } catch (const std::bad_alloc&) {
      throw over_budget(path, budget);
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(
        fmt::format("{}: cannot read grids ({}); the file may be corrupt or use a grid type OpenVDB {} "
                    "does not know",
                    path, one_line(e.what()), OPENVDB_LIBRARY_VERSION_STRING));
  }
  std::vector<GridInfo> out;
  for (const auto& g : *grids) {
    GridInfo info;
    info.name = g->getName();
    info.type = type_name(*g);
    info.grid_class = openvdb::GridBase::gridClassToString(g->getGridClass());
    info.active_voxels = g->activeVoxelCount();
    info.memory_bytes = g->memUsage();
    info.affine = g->transform().isLinear();
    openvdb::Vec3d vs = g->voxelSize();
    info.voxel_size = {vs.x(), vs.y(), vs.z()};
    openvdb::CoordBBox b = g->evalActiveVoxelBoundingBox();
    if (!b.empty()) {
      info.index_min = {b.min().x(), b.min().y(), b.min().z()};
      info.index_max = {b.max().x(), b.max().y(), b.max().z()};
      world_bbox(g->transform(), b, info.world_min, info.world_max);
    }
    if (info.active_voxels > 0)
      g->apply<openvdb::NumericGridTypes>([&](const auto& grid) {
        auto [lo, hi] = active_range(grid.tree());
        info.value_min = lo;
        info.value_max = hi;
      });
    out.push_back(std::move(info));
  }
  return out;
}

namespace {

void require_grid(const openvdb::io::File& file, const std::string& path, const std::string& grid_name,
                  const std::string& key) {
  std::vector<std::string> names = grid_names(file);
  if (std::find(names.begin(), names.end(), grid_name) == names.end())
    throw Error(fmt::format(
        "{}{}: no grid named '{}' (grids present: {}); set {} to one of these", key.empty() ? "" : key + ": ",
        path, grid_name, names.empty() ? std::string("none") : fmt::format("'{}'", fmt::join(names, "', '")),
        key.empty() ? std::string("the grid name") : key));
}

}  // namespace

void check_grid_name(const std::string& path, const std::string& grid_name, const std::string& key) {
  require_grid(*open_file(path), path, grid_name, key);
}

namespace {

// Reads grid `grid_name` of an open file (present: require_grid checked it), within the read budget.
openvdb::GridBase::Ptr read_grid(openvdb::io::File& file, const std::string& path,
                                 const std::string& grid_name) {
  try {
    ReadBudget budget(file_size(path));
    try {
      return file.readGrid(grid_name);
    } catch (const std::bad_alloc&) {
      throw over_budget(path, budget);
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(fmt::format("{}: cannot read grid '{}' ({}); the file may be corrupt", path, grid_name,
                            one_line(e.what())));
  }
}

}  // namespace

DeviceGrid load_grid(const std::string& path, const std::string& grid_name, NanPolicy nan,
                     const std::string& key) {
  auto file = open_file(path);
  require_grid(*file, path, grid_name, key);
  openvdb::GridBase::Ptr base = read_grid(*file, path, grid_name);
  auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
  if (!grid)
    throw Error(
        fmt::format("{}: grid '{}' has type {}; a scalar float (or half) density grid is needed, pick "
                    "another grid or convert it",
                    path, grid_name, type_name(*base)));
  return to_device(*grid, path, nan);
}

namespace {

// Which grids hold velocity `name`: the grid itself (true), else its components name.x, .y, .z (false).
bool velocity_is_vector(const openvdb::io::File& file, const std::string& path, const std::string& name,
                        const std::string& key) {
  std::vector<std::string> names = grid_names(file);
  auto has = [&](const std::string& n) { return std::find(names.begin(), names.end(), n) != names.end(); };
  if (has(name)) return true;
  if (has(name + ".x") && has(name + ".y") && has(name + ".z")) return false;
  throw Error(fmt::format(
      "{}: {}: no velocity grid '{}' (a vec3s grid) nor float grids '{}.x', '{}.y', '{}.z' (grids present: "
      "{}); set {} to one of these or remove the velocity",
      key, path, name, name, name, name,
      names.empty() ? std::string("none") : fmt::format("'{}'", fmt::join(names, "', '")), key));
}

}  // namespace

void check_velocity_name(const std::string& path, const std::string& grid_name, const std::string& key) {
  velocity_is_vector(*open_file(path), path, grid_name, key);
}

VelocityGrids load_velocity(const std::string& path, const std::string& grid_name, const std::string& key) {
  auto file = open_file(path);
  VelocityGrids v;
  const char* axes[3] = {"x", "y", "z"};
  if (!velocity_is_vector(*file, path, grid_name, key)) {
    v.layout = "float x/y/z";
    for (int c = 0; c < 3; ++c) {
      const std::string name = grid_name + "." + axes[c];
      openvdb::GridBase::Ptr base = read_grid(*file, path, name);
      auto grid = openvdb::gridPtrCast<openvdb::FloatGrid>(base);
      if (!grid)
        throw Error(fmt::format("{}: {}: grid '{}' has type {}; velocity components are float grids", key,
                                path, name, type_name(*base)));
      v.c[c] = to_device(*grid, path, NanPolicy::Zero);
      v.nan_voxels += v.c[c].nan_voxels;
    }
    return v;
  }
  openvdb::GridBase::Ptr base = read_grid(*file, path, grid_name);
  auto vec = openvdb::gridPtrCast<openvdb::Vec3SGrid>(base);
  if (!vec)
    throw Error(fmt::format(
        "{}: {}: grid '{}' has type {}; a velocity grid is vec3s, or float grids '{}.x', '{}.y', '{}.z'", key,
        path, grid_name, type_name(*base), grid_name, grid_name, grid_name));
  const bool staggered = vec->getGridClass() == openvdb::GRID_STAGGERED;
  v.layout = staggered ? "vec3s staggered" : "vec3s";
  const openvdb::Vec3STree& tree = vec->tree();
  for (int c = 0; c < 3; ++c) {
    // The component as a float grid of the same topology: every leaf's values (active or not, which the
    // trilinear lookup reads alike) and mask, then the active tiles above the leaves.
    auto comp = openvdb::FloatGrid::create(tree.background()[c]);
    comp->setName(grid_name + "." + axes[c]);
    comp->setTransform(vec->transform().copy());
    for (auto leaf = tree.cbeginLeaf(); leaf; ++leaf) {
      auto* dst = comp->tree().touchLeaf(leaf->origin());
      for (openvdb::Index i = 0; i < openvdb::Vec3STree::LeafNodeType::SIZE; ++i)
        dst->setValueOnly(i, leaf->getValue(i)[c]);
      dst->setValueMask(leaf->getValueMask());
    }
    auto tile = tree.cbeginValueOn();
    tile.setMaxDepth(tree.treeDepth() - 2);
    for (; tile; ++tile) {
      openvdb::CoordBBox b;
      tile.getBoundingBox(b);
      comp->tree().fill(b, (*tile)[c], true);
    }
    v.c[c] = to_device(*comp, path, NanPolicy::Zero);
    v.nan_voxels += v.c[c].nan_voxels;
    if (staggered) {
      // Component c is stored on the voxel's lower face along axis c.
      glm::dmat4 shift(1.0);
      shift[3][c] = -0.5;
      v.c[c].index_to_world = v.c[c].index_to_world * shift;
    }
  }
  return v;
}

DeviceGrid make_procedural(const ProceduralSpec& spec) {
  auto grid = build_procedural(spec);
  return to_device(*grid, fmt::format("procedural {}", spec.kind), NanPolicy::Error);
}

namespace {

// Writes beside the target and renames, so readers never see a half-written file.
void write_file(const openvdb::GridPtrVec& grids, const std::string& out_path) {
  const std::string tmp = fmt::format("{}.tmp{}", out_path, ::getpid());
  try {
    openvdb::io::File file(tmp);
    file.write(grids);
    file.close();
    // OpenVDB does not check its stream: a full disk leaves a short file. Read it back before it counts.
    try {
      openvdb::io::File check(tmp);
      check.open(false);
      for (const auto& g : grids)
        if (!check.readGrid(g->getName())) throw std::runtime_error("no grid " + g->getName());
    } catch (const std::exception& e) {
      throw std::runtime_error(
          fmt::format("the file does not read back whole, OpenVDB says '{}'", one_line(e.what())));
    }
  } catch (const std::exception& e) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw Error(
        fmt::format("{}: cannot write ({}); check that the disk has room and the directory is writable",
                    out_path, one_line(e.what())));
  }
  std::error_code ec;
  fs::rename(tmp, out_path, ec);
  if (ec) {
    std::string why = ec.message();
    fs::remove(tmp, ec);
    throw Error(fmt::format("{}: cannot rename the temporary file into place ({})", out_path, why));
  }
}

openvdb::math::Transform::Ptr to_transform(const glm::dmat4& m, const std::string& where) {
  openvdb::math::Mat4d o;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) o(i, j) = m[i][j];  // see to_glm
  try {
    return openvdb::math::Transform::createLinearTransform(o);
  } catch (const std::exception& e) {
    throw Error(
        fmt::format("{}: index_to_world is not an invertible affine map ({})", where, one_line(e.what())));
  }
}

openvdb::FloatGrid::Ptr voxel_grid(const VoxelGrid& v) {
  auto grid = openvdb::FloatGrid::create(v.background);
  grid->setName(v.name);
  grid->setTransform(to_transform(v.index_to_world, v.name));
  for (const VoxelGrid::Box& b : v.boxes)
    grid->fill(
        openvdb::CoordBBox(openvdb::Coord(b.lo.x, b.lo.y, b.lo.z), openvdb::Coord(b.hi.x, b.hi.y, b.hi.z)),
        b.value, true);
  auto acc = grid->getAccessor();
  for (const auto& [ijk, x] : v.voxels) acc.setValue(openvdb::Coord(ijk.x, ijk.y, ijk.z), x);
  return grid;
}

}  // namespace

void write_procedural(const ProceduralSpec& spec, const std::string& out_path,
                      const ProceduralExtras& extras) {
  write_procedural(spec, {{out_path, extras.offset}}, extras.velocity);
}

void write_procedural(const ProceduralSpec& spec, const std::vector<ProceduralFile>& files,
                      std::optional<glm::dvec3> velocity) {
  auto finite = [](glm::dvec3 v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
  if (velocity && !finite(*velocity))
    throw Error(fmt::format("{}: the velocity must be finite", files.empty() ? "" : files[0].path));
  openvdb::FloatGrid::Ptr density = build_procedural(spec);
  const openvdb::math::Transform::Ptr base = density->transform().copy();
  openvdb::GridPtrVec grids{density};
  if (velocity) {
    openvdb::CoordBBox box = density->evalActiveVoxelBoundingBox();
    box.expand(2);
    const char* names[3] = {"vel.x", "vel.y", "vel.z"};
    for (int c = 0; c < 3; ++c) {
      auto g = openvdb::FloatGrid::create(0.f);
      g->setName(names[c]);
      g->fill(box, float((*velocity)[c]), true);
      grids.push_back(g);
    }
  }
  for (const ProceduralFile& f : files) {
    if (!finite(f.offset)) throw Error(fmt::format("{}: the offset must be finite", f.path));
    // The voxels stay; the transform carries the offset.
    openvdb::math::Transform::Ptr xf = base->copy();
    xf->postTranslate(openvdb::Vec3d(f.offset.x, f.offset.y, f.offset.z));
    for (auto& g : grids) g->setTransform(xf->copy());
    write_file(grids, f.path);
  }
}

void write_grids(const std::vector<VoxelGrid>& grids, const std::string& out_path) {
  init_openvdb();
  openvdb::GridPtrVec out;
  for (const VoxelGrid& v : grids) {
    if (v.type == "float" || v.type == "half") {
      auto g = voxel_grid(v);
      g->setSaveFloatAsHalf(v.type == "half");
      if (v.fog_volume) g->setGridClass(openvdb::GRID_FOG_VOLUME);
      out.push_back(g);
    } else {
      throw Error(fmt::format("{}: grid '{}' has type '{}'; write_grids writes float or half", out_path,
                              v.name, v.type));
    }
  }
  write_file(out, out_path);
}

}  // namespace haze::vdb
