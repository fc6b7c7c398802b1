// Ray queries against the flattened surfaces BVH (surfaces/bvh.cpp): closest hit and occlusion.
// The kernel declares the bindings "bvh_nodes" and "bvh_triangles" (surfaces/device_surfaces.hpp).
// No ray-query extension: a stack-based walk over the binary tree, nearer child first.
#ifndef HAZE_BVH_GLSL
#define HAZE_BVH_GLSL

#include "surfaces/bvh_layout.glsl"

layout(std430, binding = BINDING_bvh_nodes) readonly buffer BvhNodes {
  GpuBvhNode bvh_nodes[];
};
layout(std430, binding = BINDING_bvh_triangles) readonly buffer BvhTriangles {
  GpuTriangle bvh_triangles[];
};

struct BvhHit {
  float t;         // tmax on a miss
  uint triangle;   // index into bvh_triangles, BVH_NONE on a miss
  uint instance;   // BVH_NONE on a miss
  uint primitive;  // BVH_NONE on a miss
  vec2 uv;         // p = (1 - u - v) v0 + u v1 + v v2
  vec3 normal;     // unit geometric normal, normalize(cross(v1 - v0, v2 - v0)); not turned to the ray
};

// Per-ray constants. The direction is rescaled by a power of two (exact) so that its largest component
// lies in [0.5, 1): box and triangle distances are then in units of the scaled direction (t' = t / scale),
// and replacing zero components by 1e-30 cannot matter at any distance a scene reaches.
struct BvhRay {
  vec3 origin;
  vec3 inv_dir;  // of the scaled direction, zero components as +-1e-30
  ivec3 k;       // kx, ky, kz; kz is the largest |direction| component
  vec3 shear;    // Sx, Sy, Sz of Woop et al. 2013
  float scale;   // scaled direction = direction * scale
};

// Widens the slab test's far distance by 2 gamma(3) (Ize 2013) so rounding in the box test never culls a
// box whose triangle the watertight test would hit.
const float BVH_FAR_SCALE = 1.0000004;

// Integer test: fast-math compilers may fold isnan/isinf away, bits they cannot.
bool bvh_finite(vec3 v) {
  uvec3 e = floatBitsToUint(v) & 0x7f800000u;
  return all(notEqual(e, uvec3(0x7f800000u)));
}

// Rays with a non-finite origin, direction or tmin, a NaN tmax, tmin > tmax, or a direction whose largest
// component is outside [1e-30, 1e30] (zero included) miss everything.
bool bvh_ray_valid(vec3 origin, vec3 direction, float tmin, float tmax) {
  vec3 a = abs(direction);
  float m = max(max(a.x, a.y), a.z);
  return bvh_finite(origin) && bvh_finite(direction) && bvh_finite(vec3(tmin)) &&
         (floatBitsToUint(tmax) & 0x7fffffffu) <= 0x7f800000u && m >= 1e-30 && m <= 1e30 && tmin <= tmax;
}

BvhRay bvh_make_ray(vec3 origin, vec3 direction) {
  BvhRay r;
  r.origin = origin;
  vec3 a = abs(direction);
  int e;
  frexp(max(max(a.x, a.y), a.z), e);
  r.scale = ldexp(1.0, -e);
  vec3 d = direction * r.scale;
  // Zero components become +-1e-30: the slab products stay finite (no 0 * inf = NaN). A ray in a box's
  // face plane would then leave the box at t = 0, which is why the host pads every box outwards.
  vec3 tiny = mix(vec3(-1e-30), vec3(1e-30), greaterThanEqual(d, vec3(0.0)));
  r.inv_dir = 1.0 / mix(d, tiny, lessThan(abs(d), vec3(1e-30)));
  int kz = a.x >= a.y ? (a.x >= a.z ? 0 : 2) : (a.y >= a.z ? 1 : 2);
  int kx = kz == 2 ? 0 : kz + 1;
  int ky = kx == 2 ? 0 : kx + 1;
  // Swapping x and y for a negative kz keeps the triangles' winding, so the sign of det tells the side.
  if (d[kz] < 0.0) {
    int s = kx;
    kx = ky;
    ky = s;
  }
  r.k = ivec3(kx, ky, kz);
  r.shear = vec3(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]);
  return r;
}

// Slab test against a node's box within (tmin, tmax); t_entry is where the ray enters it.
bool bvh_box(GpuBvhNode n, BvhRay r, float tmin, float tmax, out float t_entry) {
  vec3 t0 = (n.bmin_left_or_first.xyz - r.origin) * r.inv_dir;
  vec3 t1 = (n.bmax_count.xyz - r.origin) * r.inv_dir;
  vec3 tn = min(t0, t1), tf = max(t0, t1);
  float t_far = min(min(tf.x, tf.y), tf.z);
  t_far += abs(t_far) * (BVH_FAR_SCALE - 1.0);
  t_entry = max(max(tn.x, tn.y), max(tn.z, tmin));
  return t_entry <= min(t_far, tmax);
}

// Watertight ray/triangle test (Woop, Benthin, Wald 2013), both sides, hits in (tmin, t_max). A point on
// an edge shared by two triangles hits at least one of them: the shared vertices map to the same 2D points
// and the shared edge's functions are exact negatives (`precise` forbids fusing them into FMAs).
bool bvh_triangle(GpuTriangle tri, BvhRay r, float tmin, float t_max, out float t, out vec2 uv) {
  t = 0.0;
  uv = vec2(0.0);
  precise vec3 a = tri.v0.xyz - r.origin;
  precise vec3 b = tri.v1.xyz - r.origin;
  precise vec3 c = tri.v2.xyz - r.origin;
  a = vec3(a[r.k.x], a[r.k.y], a[r.k.z]);
  b = vec3(b[r.k.x], b[r.k.y], b[r.k.z]);
  c = vec3(c[r.k.x], c[r.k.y], c[r.k.z]);
  precise float ax = a.x - r.shear.x * a.z, ay = a.y - r.shear.y * a.z;
  precise float bx = b.x - r.shear.x * b.z, by = b.y - r.shear.y * b.z;
  precise float cx = c.x - r.shear.x * c.z, cy = c.y - r.shear.y * c.z;
  // Edge functions: twice the signed areas seen along the ray; U, V, W weight v0, v1, v2.
  precise float U = cx * by - cy * bx;
  precise float V = ax * cy - ay * cx;
  precise float W = bx * ay - by * ax;
  if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
  precise float det = U + V + W;
  if (det == 0.0) return false;
  precise float T = U * (r.shear.z * a.z) + V * (r.shear.z * b.z) + W * (r.shear.z * c.z);
  float inv_det = 1.0 / det;
  t = T * inv_det;
  if (!(t > tmin && t < t_max)) return false;
  uv = vec2(V, W) * inv_det;
  return true;
}

// The walk shared by both queries: the closest hit in (tmin, t_max), or with any_hit (a constant at every
// call site, so it folds away) the first one found. Returns the triangle or BVH_NONE; on a hit t_max
// becomes its t. Terminates for any input: each node is entered at most once (a budget of the node count
// guards even a corrupt tree) and the stack never grows past BVH_STACK_SIZE.
uint bvh_traverse(vec3 origin, vec3 direction, float tmin, inout float t_max, bool any_hit, out vec2 uv) {
  uv = vec2(0.0);
  uint hit = BVH_NONE;
  if (!bvh_ray_valid(origin, direction, tmin, t_max)) return hit;
  BvhRay r = bvh_make_ray(origin, direction);
  // Distances in units of the scaled direction (powers of two: exact).
  float t0 = tmin / r.scale, t1 = t_max / r.scale;
  float t_entry;
  if (!bvh_box(bvh_nodes[0], r, t0, t1, t_entry)) return hit;

  uint stack_node[BVH_STACK_SIZE];
  float stack_t[BVH_STACK_SIZE];
  uint sp = 0u;
  uint node = 0u;
  uint budget = uint(bvh_nodes.length());
  for (uint visit = 0u; visit < budget; ++visit) {
    GpuBvhNode n = bvh_nodes[node];
    uint first = floatBitsToUint(n.bmin_left_or_first.w);
    uint count = floatBitsToUint(n.bmax_count.w);
    if (count == BVH_INTERNAL) {
      float t_left, t_right;
      bool left = bvh_box(bvh_nodes[first], r, t0, t1, t_left);
      bool right = bvh_box(bvh_nodes[first + 1u], r, t0, t1, t_right);
      if (left && right) {
        // Nearer child now, the other on the stack with its entry distance.
        bool right_first = t_right < t_left;
        node = right_first ? first + 1u : first;
        if (sp < BVH_STACK_SIZE) {
          stack_node[sp] = right_first ? first : first + 1u;
          stack_t[sp] = right_first ? t_left : t_right;
          ++sp;
        }
        continue;
      }
      if (left || right) {
        node = left ? first : first + 1u;
        continue;
      }
    } else {
      for (uint i = first; i < first + count; ++i) {
        float t;
        vec2 b;
        if (bvh_triangle(bvh_triangles[i], r, t0, t1, t, b)) {
          t1 = t;
          uv = b;
          hit = i;
          if (any_hit) break;
        }
      }
      if (any_hit && hit != BVH_NONE) break;
    }
    // Next: the latest deferred subtree that a closer hit has not ruled out.
    bool found = false;
    while (sp > 0u && !found) {
      --sp;
      found = stack_t[sp] < t1;
      node = stack_node[sp];
    }
    if (!found) break;
  }
  if (hit != BVH_NONE) t_max = t1 * r.scale;
  return hit;
}

BvhHit bvh_closest_hit(vec3 origin, vec3 direction, float tmin, float tmax) {
  BvhHit h;
  h.t = tmax;
  h.triangle = bvh_traverse(origin, direction, tmin, h.t, false, h.uv);
  h.instance = BVH_NONE;
  h.primitive = BVH_NONE;
  h.normal = vec3(0.0);
  if (h.triangle != BVH_NONE) {
    GpuTriangle tri = bvh_triangles[h.triangle];
    h.primitive = floatBitsToUint(tri.v0.w);
    h.instance = floatBitsToUint(tri.v1.w);
    vec3 n = cross(tri.v1.xyz - tri.v0.xyz, tri.v2.xyz - tri.v0.xyz);
    // Rescaled first: a tiny triangle's squared length could underflow to 0.
    n /= max(max(abs(n.x), abs(n.y)), abs(n.z));
    vec3 d = direction / max(max(abs(direction.x), abs(direction.y)), abs(direction.z));
    h.normal = bvh_finite(n) ? normalize(n) : -normalize(d);
  }
  return h;
}

// True when any triangle lies in (tmin, tmax) along the ray: shadow rays.
bool bvh_occluded(vec3 origin, vec3 direction, float tmin, float tmax) {
  float t = tmax;
  vec2 uv;
  return bvh_traverse(origin, direction, tmin, t, true, uv) != BVH_NONE;
}

#endif
