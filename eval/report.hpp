// `haze report DIR`: one self-contained HTML file (figures embedded as data URIs) and the PNG figures beside
// it, from a sweep's results: the speed/accuracy plot with its Pareto front, per-pass time bars, memory
// ledger bars per category, and an image grid with crops and error heat maps. The plots are drawn by
// matplotlib (eval/report.py, embedded in the binary); this file aggregates and lays out.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

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

// Writes the report; returns the HTML file's path.
std::string write_report(const std::string& dir, const ReportOptions& o);

}  // namespace haze::eval
