#include "surfaces/embree_ref.hpp"

#include <embree3/rtcore.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "surfaces/bvh.hpp"
#include "surfaces/error.hpp"

namespace haze::surfaces {
namespace {

// The shader's rule (bvh_ray_valid in shaders/surfaces/bvh.glsl).
bool valid_ray(glm::vec3 o, glm::vec3 d, float tmin, float tmax) {
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(o[i]) || !std::isfinite(d[i])) return false;
  const float m = std::max(std::abs(d.x), std::max(std::abs(d.y), std::abs(d.z)));
  return std::isfinite(tmin) && !std::isnan(tmax) && m >= 1e-30f && m <= 1e30f && tmin <= tmax;
}

RTCRay make_ray(glm::vec3 o, glm::vec3 d, float tmin, float tmax) {
  RTCRay r{};
  r.org_x = o.x, r.org_y = o.y, r.org_z = o.z;
  r.dir_x = d.x, r.dir_y = d.y, r.dir_z = d.z;
  r.tnear = tmin;
  r.tfar = tmax;
  r.mask = 0xffffffffu;
  r.flags = 0;
  return r;
}

}  // namespace

EmbreeScene::EmbreeScene(std::span<const glsl::GpuTriangle> triangles)
    : triangles_(triangles.begin(), triangles.end()) {
  device_ = rtcNewDevice(nullptr);
  if (!device_)
    throw Error(fmt::format("embree: rtcNewDevice failed (error {})", int(rtcGetDeviceError(nullptr))));
  scene_ = rtcNewScene(device_);
  // Robust: Embree's most accurate triangle test, as a reference should be.
  rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_HIGH);
  if (!triangles_.empty()) {
    RTCGeometry geom = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                          3 * sizeof(float), 3 * triangles_.size()));
    auto* ix = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(
        geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), triangles_.size()));
    for (size_t i = 0; i < triangles_.size(); ++i) {
      const glsl::vec4* p[3] = {&triangles_[i].v0, &triangles_[i].v1, &triangles_[i].v2};
      for (int k = 0; k < 3; ++k) {
        v[9 * i + 3 * k + 0] = p[k]->x;
        v[9 * i + 3 * k + 1] = p[k]->y;
        v[9 * i + 3 * k + 2] = p[k]->z;
        ix[3 * i + k] = uint32_t(3 * i + k);
      }
    }
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene_, geom);
    rtcReleaseGeometry(geom);
  }
  rtcCommitScene(scene_);
  if (RTCError e = rtcGetDeviceError(device_); e != RTC_ERROR_NONE) {
    rtcReleaseScene(scene_);
    rtcReleaseDevice(device_);
    throw Error(fmt::format("embree: scene build failed (error {})", int(e)));
  }
}

EmbreeScene::~EmbreeScene() {
  rtcReleaseScene(scene_);
  rtcReleaseDevice(device_);
}

RefHit EmbreeScene::intersect(glm::vec3 origin, glm::vec3 direction, float tmin, float tmax) const {
  RefHit h;
  h.t = tmax;
  if (!valid_ray(origin, direction, tmin, tmax)) return h;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh{};
  rh.ray = make_ray(origin, direction, tmin, tmax);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(scene_, &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return h;
  const glsl::GpuTriangle& t = triangles_[rh.hit.primID];
  h.t = rh.ray.tfar;
  h.triangle = input_index(t);
  h.instance = instance_id(t);
  h.primitive = primitive_id(t);
  h.uv = {rh.hit.u, rh.hit.v};
  // The shader's formula on the same vertices, not Embree's unnormalized Ng, so the two compare directly.
  h.normal = glm::normalize(glm::cross(glm::vec3(t.v1) - glm::vec3(t.v0), glm::vec3(t.v2) - glm::vec3(t.v0)));
  return h;
}

bool EmbreeScene::occluded(glm::vec3 origin, glm::vec3 direction, float tmin, float tmax) const {
  if (!valid_ray(origin, direction, tmin, tmax)) return false;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r = make_ray(origin, direction, tmin, tmax);
  rtcOccluded1(scene_, &ctx, &r);
  return r.tfar < 0;  // Embree marks an occluded ray with tfar = -inf
}

}  // namespace haze::surfaces
