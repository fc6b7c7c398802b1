// NanoVDB-side host code: the CPU reference sampler and the world-space majorant grid.
#include <fmt/format.h>
#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/SampleFromVoxels.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "vdb/vdb.h"

namespace haze::vdb {
namespace {

const nanovdb::FloatGrid* as_grid(const void* aligned) {
  return reinterpret_cast<const nanovdb::FloatGrid*>(aligned);
}

// Where a point on the GPU may land relative to the host's cell boxes (float rounding in the world-to-index
// transform and in the DDA), in voxels.
constexpr double kIndexSlack = 0.01;
// Relative margin on majorant (minorant) values so that float trilinear results never exceed (fall below)
// them by an ulp.
constexpr double kValueMargin = 1e-5;
// Where a point on the GPU may land outside its majorant cell (float rounding in the DDA), in cells: the
// minorant counts a medium only in cells that lie inside its box with this margin.
constexpr double kCellSlack = 1e-3;
// Points per axis at which a cell's mean density is estimated (any value between the bounds is a valid
// control; the mean makes the residual small).
constexpr int kMeanPoints = 3;

float round_up(double v) {
  float f = float(v);
  return double(f) < v ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}
float round_down(double v) {
  float f = float(v);
  return double(f) > v ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
// Two floats inward of v: the device's float box (round to nearest) lies outside it.
double inward(double v, float dir) {
  const float to = dir * std::numeric_limits<float>::infinity();
  return std::nextafter(std::nextafter(dir > 0 ? round_up(v) : round_down(v), to), to);
}

// Max and min of every value (active or not) the sampler can read, per B^3 block of voxels over the index
// box [lo, hi]. The max starts at the background, which is what the tree returns where it has no node; the
// min takes the background only where some voxel of the block has no node (counted in `covered`).
struct BrickBounds {
  glm::ivec3 lo, hi, dims;
  int B;
  std::vector<float> vmax, vmin;
  float bg;

  BrickBounds(const nanovdb::FloatGrid& grid, glm::ivec3 lo_, glm::ivec3 hi_, int B_)
      : lo(lo_), hi(hi_), B(B_) {
    dims = (hi - lo) / B + 1;
    bg = grid.tree().background();
    const size_t n = size_t(dims.x) * dims.y * dims.z;
    vmax.assign(n, bg);
    vmin.assign(n, std::numeric_limits<float>::infinity());
    covered.assign(n, 0);
    // Walk the tree by hand: in NanoVDB 10.0 the node iterators' getOrigin() is broken (the root's lacks a
    // return, the internal nodes' does not compile), and RootNode hides its tiles (use data()).
    const auto* root = grid.tree().root().data();
    for (uint32_t n = 0; n < root->mTableSize; ++n) {
      const auto* tile = root->tile(n);
      if (tile->isValue())
        add_box(tile->origin(), 4096, tile->value);
      else
        visit(*root->getChild(tile));
    }
    for (int z = 0; z < dims.z; ++z)
      for (int y = 0; y < dims.y; ++y)
        for (int x = 0; x < dims.x; ++x) {
          const glm::ivec3 b(x, y, z);
          const glm::ivec3 a = lo + b * B, e = glm::min(a + (B - 1), hi);
          const glm::u64vec3 span(e - a + 1);
          if (covered[index(b)] < span.x * span.y * span.z) vmin[index(b)] = std::min(vmin[index(b)], bg);
        }
  }

  template <typename NodeT>
  void visit(const NodeT& node) {
    if (!intersects(node.origin(), int(NodeT::DIM))) return;
    if constexpr (NodeT::LEVEL == 0) {
      nanovdb::Coord o = node.origin();
      for (uint32_t i = 0; i < NodeT::SIZE; ++i) {
        glm::ivec3 c(o[0] + int(i >> 6), o[1] + int((i >> 3) & 7), o[2] + int(i & 7));
        if (glm::any(glm::lessThan(c, lo)) || glm::any(glm::greaterThan(c, hi))) continue;
        const float x = node.getValue(i);
        const size_t k = index((c - lo) / B);
        vmax[k] = std::max(vmax[k], x);
        vmin[k] = std::min(vmin[k], x);
        covered[k] += 1;
      }
    } else {
      const auto* data = node.data();
      for (uint32_t n = 0; n < NodeT::SIZE; ++n) {
        if (data->mChildMask.isOn(n))
          visit(*data->getChild(n));
        else
          add_box(node.offsetToGlobalCoord(n), int(NodeT::ChildNodeType::DIM), data->getValue(n));
      }
    }
  }

  size_t index(glm::ivec3 b) const { return (size_t(b.z) * dims.y + b.y) * dims.x + b.x; }

  bool intersects(nanovdb::Coord o, int dim) const {
    glm::ivec3 a(o[0], o[1], o[2]);
    return glm::all(glm::lessThanEqual(a, hi)) && glm::all(glm::greaterThanEqual(a + (dim - 1), lo));
  }

  // A tile of value x covering [o, o + dim).
  void add_box(nanovdb::Coord o, int dim, float x) {
    if (!intersects(o, dim)) return;
    glm::ivec3 a = glm::max(glm::ivec3(o[0], o[1], o[2]), lo),
               b = glm::min(glm::ivec3(o[0], o[1], o[2]) + (dim - 1), hi);
    glm::ivec3 ba = (a - lo) / B, bb = (b - lo) / B;
    for (int z = ba.z; z <= bb.z; ++z)
      for (int y = ba.y; y <= bb.y; ++y)
        for (int xx = ba.x; xx <= bb.x; ++xx) {
          const glm::ivec3 br(xx, y, z);
          const glm::ivec3 ca = glm::max(a, lo + br * B), cb = glm::min(b, lo + br * B + (B - 1));
          const glm::u64vec3 span(cb - ca + 1);
          const size_t k = index(br);
          vmax[k] = std::max(vmax[k], x);
          vmin[k] = std::min(vmin[k], x);
          covered[k] += span.x * span.y * span.z;
        }
  }

  // Max and min over the voxels [a, b]. The max is over the part inside the box (-inf when none is); the
  // min takes the background where [a, b] reaches outside it.
  void query(glm::ivec3 a, glm::ivec3 b, float& mx, float& mn) const {
    mx = -std::numeric_limits<float>::infinity();
    mn = glm::any(glm::lessThan(a, lo)) || glm::any(glm::greaterThan(b, hi))
             ? bg
             : std::numeric_limits<float>::infinity();
    a = glm::max(a, lo);
    b = glm::min(b, hi);
    if (glm::any(glm::greaterThan(a, b))) return;
    glm::ivec3 ba = (a - lo) / B, bb = (b - lo) / B;
    for (int z = ba.z; z <= bb.z; ++z)
      for (int y = ba.y; y <= bb.y; ++y) {
        const size_t row = index({0, y, z});
        for (int x = ba.x; x <= bb.x; ++x) {
          mx = std::max(mx, vmax[row + x]);
          mn = std::min(mn, vmin[row + x]);
        }
      }
  }

 private:
  std::vector<uint64_t> covered;  // voxels of the block some node (leaf voxel or tile) holds
};

}  // namespace

Sampler::Sampler(const DeviceGrid& g) {
  if (g.nanovdb.size() < sizeof(nanovdb::GridData))
    throw Error(
        fmt::format("grid '{}': the NanoVDB buffer is empty; load or generate the grid first", g.name));
  // NanoVDB's types are alignas(32) while std::vector only guarantees 16: copy into aligned storage.
  buf_.reset(new Aligned[(g.nanovdb.size() + 31) / 32]);
  std::memcpy(buf_.get(), g.nanovdb.data(), g.nanovdb.size());
  const auto* grid = as_grid(buf_.get());
  if (!grid->isValid() || grid->gridType() != nanovdb::GridType::Float)
    throw Error(
        fmt::format("grid '{}': the buffer is not a NanoVDB float grid; rebuild it with load_grid", g.name));
  world_to_index = glm::inverse(g.index_to_world);
}

float Sampler::trilinear(glm::dvec3 p) const {
  const auto* grid = as_grid(buf_.get());
  auto acc = grid->getAccessor();
  auto s = nanovdb::createSampler<1, decltype(acc), false>(acc);
  return s(nanovdb::Vec3d(p.x, p.y, p.z));
}

float Sampler::voxel(glm::ivec3 c) const {
  return as_grid(buf_.get())->tree().getValue(nanovdb::Coord(c.x, c.y, c.z));
}

float sample_index_trilinear(const DeviceGrid& g, glm::dvec3 index_pos) {
  return Sampler(g).trilinear(index_pos);
}

MajorantGrid build_majorant(const std::vector<MajorantInput>& media, int resolution) {
  MajorantGrid out;
  if (media.empty()) return out;
  if (resolution < 1) throw Error(fmt::format("majorant grid: resolution must be >= 1, got {}", resolution));

  struct Medium {
    size_t index;  // into media
    const DeviceGrid* g;
    glm::dmat4 w2i;
    double scale;
    glm::ivec3 lo, hi;      // index bbox dilated by one voxel
    glm::dvec3 wmin, wmax;  // its world box, clipped
    glm::dvec3 clip_min, clip_max;
  };
  std::vector<Medium> ms;
  out.value_min.assign(media.size(), std::numeric_limits<float>::infinity());
  glm::dvec3 wmin(std::numeric_limits<double>::max()), wmax = -wmin;
  for (size_t i = 0; i < media.size(); ++i) {
    const MajorantInput& in = media[i];
    if (!in.grid) throw Error(fmt::format("majorant grid: medium {} has no grid", i));
    if (!(in.density_scale >= 0) || !std::isfinite(in.density_scale))
      throw Error(
          fmt::format("majorant grid: medium {} (grid '{}') has density scale {}; it must be finite and >= 0",
                      i, in.grid->name, in.density_scale));
    glm::dmat4 i2w = in.object_to_world * in.grid->index_to_world;
    double det = glm::determinant(i2w);
    if (!(std::abs(det) > 0) || !std::isfinite(det))
      throw Error(fmt::format("majorant grid: medium {} (grid '{}') has a singular or non-finite transform",
                              i, in.grid->name));
    Medium m{i,
             in.grid,
             glm::inverse(i2w),
             in.density_scale,
             in.grid->index_min - 1,
             in.grid->index_max + 1,
             glm::dvec3(std::numeric_limits<double>::max()),
             glm::dvec3(-std::numeric_limits<double>::max()),
             in.clip_min,
             in.clip_max};
    for (int c = 0; c < 8; ++c) {
      glm::dvec3 p(c & 1 ? m.hi.x : m.lo.x, c & 2 ? m.hi.y : m.lo.y, c & 4 ? m.hi.z : m.lo.z);
      glm::dvec3 w(i2w * glm::dvec4(p, 1.0));
      m.wmin = glm::min(m.wmin, w);
      m.wmax = glm::max(m.wmax, w);
    }
    m.wmin = glm::max(m.wmin, m.clip_min);
    m.wmax = glm::min(m.wmax, m.clip_max);
    if (glm::any(glm::greaterThan(m.wmin, m.wmax))) continue;  // clipped away: nothing to bound
    wmin = glm::min(wmin, m.wmin);
    wmax = glm::max(wmax, m.wmax);
    ms.push_back(m);
  }
  if (ms.empty()) return out;
  // Round the bounds outward to float and use those from here on: the GPU finds cells from the float values.
  for (int a = 0; a < 3; ++a) {
    out.world_min[a] = round_down(wmin[a]);
    out.world_max[a] = round_up(wmax[a]);
  }
  glm::dvec3 lo(out.world_min), ext = glm::dvec3(out.world_max) - lo;
  double longest = std::max({ext.x, ext.y, ext.z});
  for (int a = 0; a < 3; ++a) out.res[a] = std::max(1, int(std::lround(resolution * ext[a] / longest)));
  glm::dvec3 cell = ext / glm::dvec3(out.res);
  const size_t ncells = size_t(out.res.x) * out.res.y * out.res.z;
  std::vector<double> acc(ncells, 0.0), acc_min(ncells, 0.0), acc_mean(ncells, 0.0);

  for (const Medium& m : ms) {
    if (m.scale == 0) continue;
    // Brick size: about a quarter of a cell's index-space extent, so a cell's query touches few bricks and
    // the coarsening loosens the bound by a fraction of a cell.
    double e = std::numeric_limits<double>::max();
    for (int j = 0; j < 3; ++j) {
      double ej = 0;
      for (int i = 0; i < 3; ++i) ej += std::abs(m.w2i[i][j]) * cell[i];
      e = std::min(e, ej);
    }
    int B = 1;
    while (B < 64 && 2.0 * B <= e / 4) B *= 2;
    glm::dvec3 span = glm::dvec3(m.hi - m.lo + 1);
    while (B < 4096 && (span.x / B + 1) * (span.y / B + 1) * (span.z / B + 1) > double(1 << 24)) B *= 2;
    Sampler sampler(*m.g);
    const nanovdb::FloatGrid& grid = *as_grid(sampler.aligned_buffer());
    const BrickBounds bricks(grid, m.lo, m.hi, B);
    out.value_min[m.index] = *std::min_element(bricks.vmin.begin(), bricks.vmin.end());

    // Where the medium is nonzero at most; a cell counts towards the minorant only inside it.
    glm::dvec3 inner_min, inner_max;
    for (int a = 0; a < 3; ++a) {
      inner_min[a] = inward(m.wmin[a], 1);
      inner_max[a] = inward(m.wmax[a], -1);
    }
    // Cells that can overlap the medium's world box.
    glm::ivec3 c0 = glm::clamp(glm::ivec3(glm::floor((m.wmin - lo) / cell)) - 1, glm::ivec3(0), out.res - 1);
    glm::ivec3 c1 = glm::clamp(glm::ivec3(glm::floor((m.wmax - lo) / cell)) + 1, glm::ivec3(0), out.res - 1);
    tbb::parallel_for(tbb::blocked_range<int>(c0.z, c1.z + 1), [&](const tbb::blocked_range<int>& r) {
      auto acc_v = grid.getAccessor();
      auto trilinear = nanovdb::createSampler<1, decltype(acc_v), false>(acc_v);
      for (int z = r.begin(); z < r.end(); ++z)
        for (int y = c0.y; y <= c1.y; ++y)
          for (int x = c0.x; x <= c1.x; ++x) {
            // Index-space box of the cell's part inside the clip box, then every voxel whose trilinear
            // support reaches into it: a point p reads voxels floor(p) and floor(p) + 1 on each axis.
            const glm::dvec3 w0 = glm::max(lo + cell * glm::dvec3(x, y, z), m.clip_min),
                             w1 = glm::min(lo + cell * glm::dvec3(x + 1, y + 1, z + 1), m.clip_max);
            if (glm::any(glm::greaterThan(w0, w1))) continue;
            glm::dvec3 a(std::numeric_limits<double>::max()), b = -a;
            for (int c = 0; c < 8; ++c) {
              glm::dvec3 w(c & 1 ? w1.x : w0.x, c & 2 ? w1.y : w0.y, c & 4 ? w1.z : w0.z);
              glm::dvec3 p(m.w2i * glm::dvec4(w, 1.0));
              a = glm::min(a, p);
              b = glm::max(b, p);
            }
            // Clamp before converting to int: far cells of a strongly scaled medium can be far out in index
            // space.
            glm::dvec3 blo = glm::dvec3(bricks.lo) - 2.0, bhi = glm::dvec3(bricks.hi) + 2.0;
            a = glm::clamp(a - kIndexSlack, blo, bhi);
            b = glm::clamp(b + kIndexSlack, blo, bhi);
            glm::ivec3 va(glm::floor(a)), vb = glm::ivec3(glm::floor(b)) + 1;
            float mx, mn;
            bricks.query(va, vb, mx, mn);
            const size_t k = (size_t(z) * out.res.y + y) * out.res.x + x;
            if (mx > 0) acc[k] += m.scale * double(mx);
            // The shader counts negative values as 0 and nothing outside the medium's box.
            const glm::dvec3 c0w = lo + cell * (glm::dvec3(x, y, z) - kCellSlack),
                             c1w = lo + cell * (glm::dvec3(x + 1, y + 1, z + 1) + kCellSlack);
            const bool inside = glm::all(glm::greaterThanEqual(c0w, inner_min)) &&
                                glm::all(glm::lessThanEqual(c1w, inner_max));
            if (inside && mn > 0) acc_min[k] += m.scale * double(mn);
            // The cell's mean density from kMeanPoints^3 stratified points (zero outside the medium's boxes).
            double sum = 0;
            for (int i = 0; i < kMeanPoints * kMeanPoints * kMeanPoints; ++i) {
              const glm::dvec3 f((i % kMeanPoints + 0.5) / kMeanPoints,
                                 (i / kMeanPoints % kMeanPoints + 0.5) / kMeanPoints,
                                 (i / (kMeanPoints * kMeanPoints) + 0.5) / kMeanPoints);
              const glm::dvec3 w = lo + cell * (glm::dvec3(x, y, z) + f);
              if (glm::any(glm::lessThan(w, m.clip_min)) || glm::any(glm::greaterThan(w, m.clip_max)))
                continue;
              const glm::dvec3 q(m.w2i * glm::dvec4(w, 1.0));
              if (glm::any(glm::lessThan(q, glm::dvec3(m.lo))) ||
                  glm::any(glm::greaterThan(q, glm::dvec3(m.hi))))
                continue;
              sum += std::max(double(trilinear(nanovdb::Vec3d(q.x, q.y, q.z))), 0.0);
            }
            acc_mean[k] += m.scale * sum / double(kMeanPoints * kMeanPoints * kMeanPoints);
          }
    });
  }
  out.sigma_max.resize(ncells);
  for (size_t i = 0; i < ncells; ++i)
    out.sigma_max[i] = acc[i] > 0 ? round_up(acc[i] * (1 + kValueMargin)) : 0.f;
  out.sigma_min.resize(ncells);
  for (size_t i = 0; i < ncells; ++i)
    out.sigma_min[i] = acc_min[i] > 0 ? round_down(acc_min[i] * (1 - kValueMargin)) : 0.f;
  out.sigma_mean.resize(ncells);
  for (size_t i = 0; i < ncells; ++i)
    out.sigma_mean[i] = std::clamp(float(acc_mean[i]), out.sigma_min[i], out.sigma_max[i]);
  return out;
}

}  // namespace haze::vdb
