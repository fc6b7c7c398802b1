// `haze report DIR`: one self-contained HTML file (figures embedded as data URIs) and the PNG figures beside
// it, from a sweep's results: the speed/accuracy plot with its Pareto front, per-pass time bars, memory
// ledger bars per category, and an image grid with crops and error heat maps. The plots are drawn by
// matplotlib (eval/report.py, embedded in the binary); this file aggregates and lays out.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

namespace haze::eval {

struct ReportOptions {
  std::string out;                // the HTML file; default DIR/report.html (figures in DIR/report/)
  std::string metric = "relmse";  // the error axis: relmse, smape, mse, flip_ldr, flip_hdr
  int max_images = 6;             // image columns besides the reference
};

// The runs grouped by setting (seeds pooled): mean time, mean and sd of the metric, per-pass times, memory
// per category, and whether the group is on the Pareto front of (time, error). Throws Error for a DIR
// without results (naming what to run).
nlohmann::json report_data(const std::string& dir, const ReportOptions& o);

// The label of a setting ("a.b.c=1, d=2") and its short form (each path's last part), without the keys the
// setting does not use (a.b.x while a.b.enabled is false).
std::pair<std::string, std::string> setting_labels(const nlohmann::json& settings);

// The equal-time table of result rows: the rows form curves (their settings without render.seed and the
// cost axis, render.spp or render.time_budget_s), each curve's error against GPU ms per frame is
// interpolated linearly in log-log (never extrapolated), and at a few budgets inside the range every curve
// covers (its ends and their geometric mean) the curve with the lowest error wins. For each other curve:
// its error, the ratio of its error to the winner's on the seed-mean curves, and the mean and sd of that
// ratio over the seeds both curves have (each seed's own curve). {"cost_axis", "metric", "curves": [label],
// "budgets": [{"ms", "winner", "rows": [{"label", "short", "error", "ratio", "ratio_mean", "ratio_sd",
// "seeds"}]}], "note"}; null without a cost axis or with fewer than two curves.
nlohmann::json equal_time_table(const std::vector<nlohmann::json>& rows, const std::string& metric);

// The written summary that opens the report (plain text, one sentence per entry): what was run, the
// references that did not converge, the equal-time winners with their margins, the Pareto settings.
std::vector<std::string> report_summary(const nlohmann::json& data);

// Writes the report; returns the HTML file's path.
std::string write_report(const std::string& dir, const ReportOptions& o);

}  // namespace haze::eval
