#pragma once
// Every device allocation haze makes, so memory budgets can be reported per buffer and per category.

#include <cstdint>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace haze::gpu {

struct LedgerEntry {
  std::string name, category, format;
  uint64_t bytes;          // allocated (VkMemoryRequirements.size)
  uint64_t requested = 0;  // what the caller asked for; can be less than bytes (alignment, 4-byte minimum)
};

// Thread-safe: pipelines and buffers may be created from several threads.
class MemoryLedger {
 public:
  uint64_t add(LedgerEntry e);               // returns an id for remove()
  void remove(uint64_t id);                  // unknown ids are ignored
  std::vector<LedgerEntry> entries() const;  // live ones, insertion order
  uint64_t total() const;                    // sum of allocated bytes
  uint64_t total_requested() const;
  std::map<std::string, uint64_t> per_category() const;
  uint64_t peak() const;  // peak of total() since creation or reset_peak()
  void reset_peak();      // peak = total(): a sweep measures each run's own peak
  // {"entries":[{name,category,format,bytes,requested}], "per_category":{...}, "total":N, "peak":N}
  nlohmann::json to_json() const;

 private:
  mutable std::mutex mutex_;
  std::map<uint64_t, LedgerEntry> live_;  // ids grow, so map order is insertion order
  uint64_t next_id_ = 1;
  uint64_t total_ = 0;
  uint64_t peak_ = 0;
};

}  // namespace haze::gpu
