// `haze sweep`: a base scene, axes of dotted-path values (cartesian, zipped or one at a time), seeds and
// frames. Each run's settings, per-pass GPU times, memory ledger and metrics against a cached reference are
// appended to DIR/results.jsonl (and DIR/results.csv rewritten) the moment the run finishes, so re-running
// the same command skips finished runs. The file format is in docs/workflow.md.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "eval/reference.hpp"
#include "gpu/gpu.hpp"
#include "render/renderer.hpp"

namespace haze::eval {

// One axis: a dotted path (or several set together) and its values.
struct Axis {
  std::vector<std::string> paths;
  std::vector<nlohmann::json> values;  // one value per path-set: a value, or an array of paths.size()
};

struct SweepSpec {
  std::string file;              // the sweep file, for messages
  std::string scene;             // the base scene, resolved against the sweep file's folder
  std::vector<std::string> set;  // fixed "path=value" overrides, the file's "set" then --set
  std::vector<Axis> axes;
  std::string combine = "cartesian";  // cartesian | zip | each (one axis at a time, the others at base)
  std::vector<uint32_t> seeds;        // render.seed of each repetition; empty: the scene's
  std::string frames;                 // "A:B"; "": the scene's render.frames
  std::optional<ReferenceOptions> reference;  // none: no error metrics
  std::string layer;                 // the layer compared, the same in test and reference ("": R, G, B)
  bool require_finite = true;        // a run with NaN, Inf or discarded samples makes the sweep exit with 4
  std::string save_images = "last";  // last | all | none: EXR frames kept per run (for the report)
  nlohmann::json canonical;          // everything above as JSON: what identifies the sweep
};

struct Run {
  size_t index = 0;  // position in the sweep's order: axes (first outermost), then seeds
  std::string id;    // hash of overrides and frames: stable across machines and re-runs
  nlohmann::json settings = nlohmann::json::object();  // {"path": value} of the axes and render.seed
  std::vector<std::string> overrides;                  // set, axes and seed as "path=value"
};

// Reads and checks a sweep file: unknown keys, an empty or ragged axis, wrong types. `cli_set` are extra
// fixed overrides. Throws Error "<file>: <key>: ... " before anything runs.
SweepSpec load_sweep(const std::string& path, const std::vector<std::string>& cli_set = {});
std::vector<Run> expand(const SweepSpec& spec);
// Loads the scene of every axis value and every run, so that an unknown path, a wrong type or an
// out-of-range value fails before the first run starts. Throws Error naming the sweep file and axis.
void check_runs(const SweepSpec& spec, const std::vector<Run>& runs);

struct Shard {
  int index = 0, count = 1;  // runs with run.index % count == index
};
Shard parse_shard(const std::string& text);  // "i/N" with 0 <= i < N
std::vector<Run> shard_runs(const std::vector<Run>& runs, Shard shard);
// Where a shard writes: DIR itself unsharded, else DIR/shard-<i>-of-<N>.
std::string shard_dir(const std::string& out, Shard shard);

// Rows of a results.jsonl. A torn last line (a run killed while writing) is dropped and the file
// rewritten without it.
std::vector<nlohmann::json> read_results(const std::string& path);
// results.csv of `rows`: one column per setting, time, memory and metric, union over the rows.
std::string results_csv(const std::vector<nlohmann::json>& rows);

// A result row's figures in render::summary_of_stats's form (for render::format_summary).
nlohmann::json summary_of_row(const nlohmann::json& row);

// `haze stats DIR`: the summary of a `haze render` folder (its stats.json), of every run of a sweep folder
// (its results.jsonl), or of one run (DIR/runs/<id>). Throws Error naming DIR and what it expected.
std::string stats_text(const std::string& dir);

// NaN and Inf among every layer haze writes for `img` (what require_finite checks).
size_t count_nonfinite(const render::Image& img);

struct SweepHooks {
  std::function<void(const std::string&)> log;  // one line
  // After each run; reference_s: seconds this call spent making references so far (not part of any run).
  std::function<void(size_t done, size_t total, const nlohmann::json* row, double reference_s)> progress;
};

// Runs the shard's unfinished runs. Returns the exit code: 0, or 4 when require_finite and a run had NaN
// or Inf. Validation messages are the caller's to check.
int run_sweep(gpu::Context& ctx, const SweepSpec& spec, const std::string& out, Shard shard,
              const SweepHooks& hooks);

// Joins DIR/results.jsonl and DIR/shard-*/results.jsonl into DIR/results.jsonl and results.csv, each run
// once. Throws Error listing what is missing (after writing what is there).
nlohmann::json merge_sweep(const SweepSpec& spec, const std::string& out);

}  // namespace haze::eval
