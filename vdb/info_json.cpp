// JSON form of inspect() results, for `haze vdb` and stats files.
#include "vdb/vdb.h"

namespace haze::vdb {
namespace {
template <typename V>
nlohmann::json vec3(const V& v) {
  return nlohmann::json::array({v.x, v.y, v.z});
}
bool is_scalar(const std::string& type) {
  return type == "float" || type == "half" || type == "double" || type == "int32" || type == "int64";
}
}  // namespace

nlohmann::json to_json(const GridInfo& g) {
  nlohmann::json j = {{"name", g.name},
                      {"type", g.type},
                      {"class", g.grid_class},
                      {"index_min", vec3(g.index_min)},
                      {"index_max", vec3(g.index_max)},
                      {"world_min", vec3(g.world_min)},
                      {"world_max", vec3(g.world_max)},
                      {"voxel_size", vec3(g.voxel_size)},
                      {"active_voxels", g.active_voxels},
                      {"memory_bytes", g.memory_bytes},
                      {"affine", g.affine}};
  // Value ranges exist for scalar grids only; null says "not applicable" rather than a misleading 0.
  j["value_min"] = is_scalar(g.type) && g.active_voxels ? nlohmann::json(g.value_min) : nlohmann::json();
  j["value_max"] = is_scalar(g.type) && g.active_voxels ? nlohmann::json(g.value_max) : nlohmann::json();
  return j;
}

nlohmann::json to_json(const std::vector<GridInfo>& grids) {
  nlohmann::json j = nlohmann::json::array();
  for (const auto& g : grids) j.push_back(to_json(g));
  return j;
}

}  // namespace haze::vdb
