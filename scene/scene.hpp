// The scene description: plain data read from JSON (docs/scene-format.md), no GPU, no OpenVDB.
// Every struct lists its fields once in reflect() below; reading, writing, --set and the docs follow it.
#pragma once

#include <cstdint>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "denoise/params.hpp"
#include "guiding/params.hpp"
#include "reflect/params.hpp"

namespace haze::scene {

// The scene is read, written, overridden and described through reflect/params.hpp; its errors are
// reflection::Error (one line naming the file and key).
using reflection::Choices;
using reflection::Error;
using reflection::format_params;
using reflection::ParamInfo;
using reflection::Range;
using reflection::ReadContext;
using reflection::Where;

// Frames are numbered 0..kMaxFrame (keys, render.frames, --frames).
inline constexpr int kMaxFrame = 9'999'999;

struct Camera {
  glm::vec3 position{0, 1, 5};
  glm::vec3 target{0, 1, 0};
  glm::vec3 up{0, 1, 0};
  float fov_y = 45.f;  // vertical field of view in degrees, (0, 180)
};

struct Transform {
  glm::vec3 translate{0};
  glm::vec3 rotate{0};  // Euler angles in degrees: about x, then y, then z (world axes)
  glm::vec3 scale{1};   // components nonzero
  // Object to world: translate * Rz * Ry * Rx * scale.
  glm::mat4 matrix() const;
};

struct Emission {
  std::string mode = "none";  // none | blackbody | scale
  std::string grid = "temperature";
  float scale = 1.f;
  float temperature_scale = 1.f;  // kelvin per grid unit, for blackbody
};

// The velocity of a VDB medium's contents: its virtual points move with it between frames (the volume
// motion vectors, docs/rendering.md "Volume motion"), on top of the medium's transform.
struct Velocity {
  std::string grid = "vel";     // a vec3 grid of the medium's file, or its float grids grid.x, .y, .z
  float scale = 1.f;            // multiplier on the grid's vectors
  std::string unit = "second";  // second: world units per second (a frame is 1 / fps) | frame: per frame
};

// One VDB medium.
struct Medium {
  // A .vdb; relative paths are resolved against Scene::base_dir on load. A run of '#' makes it a
  // sequence: "smoke_####.vdb" is smoke_0007.vdb at frame 7 (scene/animation.hpp)...
  std::string file;
  std::optional<nlohmann::json> procedural;  // ...or a procedural spec {"kind": ...} checked by vdb/
  std::string grid = "density";
  float density_scale = 1.f;     // >= 0
  glm::vec3 albedo{0.9f};        // each in [0, 1]
  glm::vec3 sigma_t_color{1.f};  // RGB multipliers of sigma_t (chromatic extinction), >= 0
  float g = 0.f;                 // HG anisotropy in [-1, 1]; the renderer clamps to +-0.99 and reports it
  Emission emission;
  Transform transform;
  // World-space box the medium is clipped to: zero outside it, exactly (no trilinear fringe beyond a
  // face). The defaults leave it unbounded.
  glm::vec3 bounds_min{-1e30f};
  glm::vec3 bounds_max{1e30f};
  std::optional<Velocity> velocity;  // absent: the contents move only with the transform
};

// A triangle mesh instance with a Lambertian material.
struct Surface {
  std::string file;                    // an .obj, relative to the scene file's folder...
  std::optional<nlohmann::json> mesh;  // ...or a built-in primitive {"kind": ...} checked by surfaces/
  glm::vec3 albedo{0.8f};              // each in [0, 1]
  std::string albedo_texture;          // an image multiplied with albedo, relative like file; "" for none
  glm::vec3 emission{0.f};             // emitted radiance (>= 0); emitters are lights for NEE
  Transform transform;
};

// Homogeneous fog, everywhere or inside an axis-aligned box.
struct Haze {
  float sigma_t = 0.05f;         // extinction per world unit, >= 0
  glm::vec3 sigma_t_color{1.f};  // RGB multipliers of sigma_t (chromatic extinction), >= 0
  glm::vec3 albedo{0.9f};
  float g = 0.f;
  bool bounded = false;
  glm::vec3 bounds_min{-1e3f};
  glm::vec3 bounds_max{1e3f};
};

struct Sun {
  glm::vec3 direction{0, 1, 0};  // towards the sun; nonzero, normalised on load
  float irradiance = 5.f;
  glm::vec3 color{1};
  float angular_diameter = 0.53f;  // degrees, [0, 30]
};

struct PointLight {
  glm::vec3 position{0};
  glm::vec3 color{1};
  float intensity = 10.f;  // radiant intensity (W/sr-like), >= 0
};

struct SpotLight {
  glm::vec3 position{0};
  glm::vec3 direction{0, -1, 0};  // nonzero, normalised on load
  glm::vec3 color{1};
  float intensity = 10.f;
  float cone_angle = 30.f;    // degrees from the axis to the edge of the cone, (0, 90]
  float falloff_angle = 5.f;  // degrees of smooth fade ending at the edge, [0, cone_angle]
};

// Light arriving from infinitely far away in every direction: constant radiance color * intensity, or a
// latitude-longitude map (file) times intensity, turned by rotate degrees about +y (lights/environment.hpp
// says how a map's pixels face the world). A map and a nonzero color are refused together.
struct Environment {
  glm::vec3 color{0};
  float intensity = 1.f;
  std::string file;    // .exr, .hdr or .png; relative to the scene file's folder; "" for a constant
  float rotate = 0.f;  // degrees about +y, counter-clockwise seen from above
};

struct Lights {
  std::optional<Sun> sun;
  std::vector<PointLight> points;
  std::vector<SpotLight> spots;
  std::optional<Environment> environment;
  std::string choice = "power";  // how next-event estimation picks a light: power | uniform
};

struct RenderSettings {
  int width = 320;
  int height = 180;
  int spp = 16;
  float time_budget_s = 0.f;  // > 0: samples until this much sampling time per frame is spent (spp unused)
  int volume_samples = 1;     // distance samples per camera sample
  int max_depth = 1;          // scattering events per path: 1 = single scattering
  uint32_t seed = 1;
  int majorant_resolution = 32;  // majorant cells along the longest axis of the media bounds
  float exposure = 0.f;          // EV applied to the PNG preview
  std::string tonemap = "aces";  // aces | reinhard | clamp
  std::vector<std::string> outputs = {"exr", "png", "stats"};
  bool pixel_jitter = true;              // random position inside the pixel (off: pixel centres)
  float equiangular_probability = 0.5f;  // share of equi-angular sampling when point/spot lights exist
  float rr_threshold = 0.1f;             // Russian roulette on ratio-tracked transmittance below this
  // The default estimator's walk in sunlit media: a lobe towards the sun mixed into phase sampling.
  float sun_walk_probability = 0.2f;
  float sun_walk_g = 0.6f;
  // The default estimator's walks from a camera sample's first medium vertex, each with 1/K of its
  // throughput.
  int walk_splits = 0;  // 0: learned
  // "default": haze's estimator (docs/rendering.md); "volpath": pbrt-v4's VolPathIntegrator for grey media,
  // the baseline of the efficiency benchmark.
  std::string estimator = "default";
  // "power": walk rays that escape to the environment or hit an emissive triangle add their power-heuristic
  // share and NEE the rest; "nee": NEE alone carries those lights (docs/rendering.md, "Lights").
  std::string mis = "power";
  std::string frames;  // "A:B", both included; "" = the animation's first to last key (0:0 without one)
  float fps = 24.f;    // time base: frame k is at k / fps seconds

  bool wants(std::string_view output) const;  // is `output` listed in outputs
};

// One keyframe. `value` is a number or [x, y, z], as the track's target; checked against the scene.
struct Key {
  int frame = -1;  // required; -1 marks it absent
  nlohmann::json value;
};

// Keyframes for one number or [x, y, z] of the scene, addressed by its dotted path as in --set
// ("camera.position", "media[0].transform.rotate", "lights.sun.irradiance", "camera.position.1").
struct Track {
  std::string path;
  std::string interpolation = "linear";  // linear | smooth
  std::vector<Key> keys;                 // frames strictly increasing; held before the first, after the last
};

// Evaluated per frame by scene_at_frame (scene/animation.hpp).
struct Animation {
  std::vector<Track> tracks;
};

struct Scene {
  Camera camera;
  std::vector<Medium> media;
  std::vector<Surface> surfaces;
  std::optional<Haze> haze;
  Lights lights;
  RenderSettings render;
  denoise::DenoiseSettings denoise;
  guiding::GuidingParams guiding;
  std::optional<Animation> animation;
  std::string path;      // the file it came from (for messages), "" if from memory
  std::string base_dir;  // folder used to resolve relative file paths
};

// Reads a scene file. `overrides` are "dotted.path=value" assignments applied to the JSON before it is
// read (see apply_override). Relative media files are resolved against the file's folder and must exist
// (a sequence: for every frame of frame_range). An animated scene is checked at every frame of that range;
// render a frame with scene_at_frame (scene/animation.hpp).
Scene load(const std::string& path, const std::vector<std::string>& overrides = {});
// `origin` names the source in messages; relative media files are resolved against `base_dir` (if
// nonempty) but not checked for existence. Animation is checked as in load.
Scene from_json(const nlohmann::json& j, const std::string& origin, const std::string& base_dir);
// Every setting, defaults included: what stats.json records. from_json(to_json(s)) reproduces s.
nlohmann::json to_json(const Scene& s);
// "render.spp=64", "media.0.density_scale=2", "lights.sun.irradiance=3", "camera.position=[0,2,8]".
// The value is JSON if it parses as JSON, else a string (with "x,y,z" and "a,b" accepted for vectors and
// string lists); a path the schema lacks, or an array element the JSON lacks, throws Error.
void apply_override(nlohmann::json& j, const std::string& assignment, const std::string& origin);

// Every scene parameter's dotted path, type, default, range and help ("media[].albedo").
std::vector<ParamInfo> describe();

// Cross-field checks, run after each object is read (found by argument-dependent lookup).
void validate(Camera& c, const Where& w);
void validate(Transform& t, const Where& w);
void validate(Emission& e, const Where& w);
void validate(Velocity& v, const Where& w);
void validate(Medium& m, const Where& w);
void validate(Surface& m, const Where& w);
void validate(Haze& h, const Where& w);
void validate(Sun& s, const Where& w);
void validate(SpotLight& s, const Where& w);
void validate(RenderSettings& r, const Where& w);
void validate(Key& k, const Where& w);
void validate(Track& t, const Where& w);

template <class V>
void reflect(V& v, Camera& c) {
  v.field("position", c.position, "eye position, world units");
  v.field("target", c.target, "point the camera looks at; must differ from position");
  v.field("up", c.up, "up direction; must not be parallel to target - position");
  v.field("fov_y", c.fov_y, Range::open(0, 180), "vertical field of view, degrees");
}

template <class V>
void reflect(V& v, Transform& t) {
  v.field("translate", t.translate, "translation, world units");
  v.field("rotate", t.rotate, "Euler angles in degrees, applied about x, then y, then z");
  v.field("scale", t.scale, "scale per axis; components nonzero");
}

template <class V>
void reflect(V& v, Emission& e) {
  v.field(
      "mode", e.mode, Choices{"none", "blackbody", "scale"},
      "none; blackbody: grid * temperature_scale is a temperature in kelvin; scale: radiance = grid * scale");
  v.field("grid", e.grid, "float grid that drives emission");
  v.field("scale", e.scale, Range::at_least(0), "multiplier on the emitted radiance");
  v.field("temperature_scale", e.temperature_scale, Range::at_least(0), "kelvin per grid unit (blackbody)");
}

template <class V>
void reflect(V& v, Velocity& e) {
  v.field("grid", e.grid,
          "velocity grid of the medium's file: a vec3 grid (staggered ones too), or float grids named "
          "grid.x, grid.y, grid.z");
  v.field("scale", e.scale, Range{-1e6, 1e6}, "multiplier on the grid's vectors");
  v.field("unit", e.unit, Choices{"second", "frame"},
          "second: world units per second (a frame lasts 1 / render.fps); frame: world units per frame");
}

template <class V>
void reflect(V& v, Medium& m) {
  v.field("file", m.file,
          ".vdb file, relative to the scene file's folder; a run of # is the frame number (a sequence); "
          "exactly one of file/procedural");
  v.field("procedural", m.procedural,
          "procedural volume spec {\"kind\": ...}; exactly one of file/procedural");
  v.field("grid", m.grid, "name of the float density grid");
  v.field("density_scale", m.density_scale, Range::at_least(0), "sigma_t = density_scale * density");
  v.field("albedo", m.albedo, Range{0, 1}, "single-scattering albedo per RGB channel");
  v.field("sigma_t_color", m.sigma_t_color, Range{0, 1e6},
          "RGB multipliers of sigma_t (chromatic extinction); not all 0 while density_scale > 0");
  v.field("g", m.g, Range{-1, 1}, "Henyey-Greenstein anisotropy (clamped to +-0.99 by the renderer)");
  v.field("emission", m.emission, "emission from a grid");
  v.field("transform", m.transform, "placement of the volume in the world");
  v.field(
      "bounds_min", m.bounds_min,
      "world-space box the medium is clipped to (zero outside it, exactly), lower corner; default unbounded");
  v.field("bounds_max", m.bounds_max, "upper corner of that box; each component > bounds_min's");
  v.field("velocity", m.velocity,
          "velocity grid that moves the medium's virtual points between frames (volume motion vectors), "
          "on top of its transform; absent: the transform alone");
}

template <class V>
void reflect(V& v, Surface& m) {
  v.field("file", m.file, ".obj file, relative to the scene file's folder; exactly one of file/mesh");
  v.field(
      "mesh", m.mesh,
      "built-in mesh {\"kind\": plane|box|sphere|window|perforated_panel, ...}; exactly one of file/mesh");
  v.field("albedo", m.albedo, Range{0, 1}, "Lambertian reflectance per RGB channel");
  v.field(
      "albedo_texture", m.albedo_texture,
      "image (PNG, JPEG, HDR, ...) multiplied with albedo at the mesh's uvs, relative to the scene file's "
      "folder; 8/16-bit images are sRGB, HDR linear; \"\" for none");
  v.field("emission", m.emission, Range::at_least(0), "emitted radiance per RGB channel (0: not a light)");
  v.field("transform", m.transform, "placement of the mesh in the world");
}

template <class V>
void reflect(V& v, Haze& h) {
  v.field("sigma_t", h.sigma_t, Range::at_least(0), "extinction coefficient per world unit");
  v.field("sigma_t_color", h.sigma_t_color, Range{0, 1e6},
          "RGB multipliers of sigma_t (chromatic extinction); not all 0 while sigma_t > 0");
  v.field("albedo", h.albedo, Range{0, 1}, "single-scattering albedo per RGB channel");
  v.field("g", h.g, Range{-1, 1}, "Henyey-Greenstein anisotropy");
  v.field("bounded", h.bounded, "false: fills all space; true: only the box bounds_min..bounds_max");
  v.field("bounds_min", h.bounds_min, "lower corner of the box (when bounded)");
  v.field("bounds_max", h.bounds_max, "upper corner of the box (when bounded); each component > bounds_min");
}

template <class V>
void reflect(V& v, Sun& s) {
  v.field("direction", s.direction, "direction towards the sun; nonzero, normalised on load");
  v.field("irradiance", s.irradiance, Range::at_least(0), "irradiance on a surface facing the sun");
  v.field("color", s.color, Range::at_least(0), "RGB tint, multiplies irradiance");
  v.field("angular_diameter", s.angular_diameter, Range{0, 30}, "apparent size of the sun disc, degrees");
}

template <class V>
void reflect(V& v, PointLight& p) {
  v.field("position", p.position, "position, world units");
  v.field("color", p.color, Range::at_least(0), "RGB tint, multiplies intensity");
  v.field("intensity", p.intensity, Range::at_least(0), "radiant intensity (power per steradian)");
}

template <class V>
void reflect(V& v, SpotLight& s) {
  v.field("position", s.position, "position, world units");
  v.field("direction", s.direction, "axis of the cone; nonzero, normalised on load");
  v.field("color", s.color, Range::at_least(0), "RGB tint, multiplies intensity");
  v.field("intensity", s.intensity, Range::at_least(0), "radiant intensity on the axis");
  v.field("cone_angle", s.cone_angle, Range{0, 90, true}, "degrees from the axis to the edge of the cone");
  v.field("falloff_angle", s.falloff_angle, Range{0, 90},
          "degrees of smooth fade ending at the edge; <= cone_angle");
}

template <class V>
void reflect(V& v, Environment& e) {
  v.field("color", e.color, Range::at_least(0),
          "RGB radiance from every direction; must stay [0, 0, 0] when file is given");
  v.field("intensity", e.intensity, Range::at_least(0), "multiplier on color, or on the map's radiance");
  v.field("file", e.file,
          "latitude-longitude radiance map (OpenEXR .exr with R, G, B channels; Radiance .hdr; 8/16-bit "
          ".png as sRGB), relative to the scene file's folder; \"\" for the constant color");
  v.field("rotate", e.rotate, Range{-360, 360},
          "degrees the map is turned about +y (counter-clockwise seen from above)");
}

template <class V>
void reflect(V& v, Lights& l) {
  v.field("sun", l.sun, "distant light with a small disc");
  v.field("points", l.points, "point lights");
  v.field("spots", l.spots, "spot lights");
  v.field("environment", l.environment, "light from every direction: a constant radiance or a map");
  v.field("choice", l.choice, Choices{"power", "uniform"},
          "how next-event estimation picks one light: by estimated power (an alias table) or uniformly");
}

template <class V>
void reflect(V& v, RenderSettings& r) {
  v.field("width", r.width, Range{1, 16384}, "image width, pixels");
  v.field("height", r.height, Range{1, 16384}, "image height, pixels");
  v.field("spp", r.spp, Range{1, 1 << 20}, "camera samples per pixel");
  v.field("time_budget_s", r.time_budget_s, Range{0, 86400},
          "seconds of sampling per frame: above 0, samples are added until it is spent (at least one) and "
          "spp is unused");
  v.field("volume_samples", r.volume_samples, Range{1, 64}, "distance samples per camera sample");
  v.field("max_depth", r.max_depth, Range{0, 256},
          "scattering events per path: 0 = emission and attenuation only, 1 = single scattering");
  v.field("seed", r.seed, "random seed");
  v.field("majorant_resolution", r.majorant_resolution, Range{1, 512},
          "majorant grid cells along the longest axis of the media bounds");
  v.field("exposure", r.exposure, Range{-64, 64}, "exposure of the PNG preview, EV");
  v.field("tonemap", r.tonemap, Choices{"aces", "reinhard", "clamp"}, "tone curve of the PNG preview");
  v.field("outputs", r.outputs, Choices{"exr", "png", "stats"}, "files to write (each at most once)");
  v.field("pixel_jitter", r.pixel_jitter, "jitter camera rays inside the pixel (false: pixel centres)");
  v.field("equiangular_probability", r.equiangular_probability, Range{0, 1},
          "mixture weight of equi-angular distance sampling (scenes with point or spot lights)");
  v.field("rr_threshold", r.rr_threshold, Range{0, 1},
          "Russian roulette on ratio-tracked transmittance below this value (a shadow ray's on T times its "
          "contribution relative to the path's first vertex; 0: off)");
  v.field("sun_walk_probability", r.sun_walk_probability, Range{0, 0.9},
          "default estimator, multiple scattering under a sun: probability that a walk's direction at a "
          "medium vertex is drawn from a lobe towards the sun instead of the phase function (0: off)");
  v.field("sun_walk_g", r.sun_walk_g, Range{0, 0.95},
          "Henyey-Greenstein g of the walk's sun lobe (sun_walk_probability)");
  v.field(
      "walk_splits", r.walk_splits, Range{0, 16},
      "default estimator, multiple scattering: walks started from each camera sample's first medium vertex, "
      "each with 1/K of its throughput (they share the camera ray's tracking and that vertex's NEE; 1: one; "
      "0: K learned from the variances and costs of earlier samples)");
  v.field("estimator", r.estimator, Choices{"default", "volpath"},
          "default: haze's estimator; volpath: pbrt-v4's VolPathIntegrator (delta tracking, NEE at every "
          "collision), the efficiency benchmark's baseline");
  v.field("mis", r.mis, Choices{"power", "nee"},
          "power: walk rays that escape to the environment or hit an emissive triangle add their "
          "power-heuristic share, NEE the rest; nee: NEE alone carries those lights");
  v.field(
      "frames", r.frames,
      "frames to render, \"A:B\" with both included; \"\": the animation's first to last key (0:0 without)");
  v.field("fps", r.fps, Range{0, 1000, true}, "frames per second: frame k is at time k / fps seconds");
}

template <class V>
void reflect(V& v, Key& k) {
  v.field("frame", k.frame, Range{0, kMaxFrame}, "frame number (required)");
  v.field("value", k.value, "value at this frame: a number or [x, y, z], like the target");
}

template <class V>
void reflect(V& v, Track& t) {
  v.field("path", t.path, "dotted path of the animated number or [x, y, z], e.g. \"camera.position\"");
  v.field("interpolation", t.interpolation, Choices{"linear", "smooth"},
          "linear; smooth: monotone cubic, eased at the first and last key, no overshoot");
  v.field("keys", t.keys, "keyframes {\"frame\": F, \"value\": V} in increasing frame order");
}

template <class V>
void reflect(V& v, Animation& a) {
  v.field("tracks", a.tracks, "one track per animated value");
}

template <class V>
void reflect(V& v, Scene& s) {
  v.field("camera", s.camera, "the pinhole camera");
  v.field("media", s.media, "VDB or procedural media");
  v.field("surfaces", s.surfaces, "triangle meshes (OBJ files or built-in primitives)");
  v.field("haze", s.haze, "homogeneous fog");
  v.field("lights", s.lights, "light sources");
  v.field("render", s.render, "render settings");
  v.field("denoise", s.denoise, "the SVGF denoiser instances");
  v.field("guiding", s.guiding, "distance guiding along camera rays (docs/guiding.md)");
  v.field("animation", s.animation, "keyframed tracks; frames of a VDB sequence come from media[].file");
}

}  // namespace haze::scene
