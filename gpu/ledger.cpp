#include "gpu/ledger.hpp"

namespace haze::gpu {

uint64_t MemoryLedger::add(LedgerEntry e) {
  std::lock_guard lock(mutex_);
  uint64_t id = next_id_++;
  total_ += e.bytes;
  if (total_ > peak_) peak_ = total_;
  live_.emplace(id, std::move(e));
  return id;
}

void MemoryLedger::remove(uint64_t id) {
  std::lock_guard lock(mutex_);
  auto it = live_.find(id);
  if (it == live_.end()) return;
  total_ -= it->second.bytes;
  live_.erase(it);
}

std::vector<LedgerEntry> MemoryLedger::entries() const {
  std::lock_guard lock(mutex_);
  std::vector<LedgerEntry> out;
  out.reserve(live_.size());
  for (const auto& [id, e] : live_) out.push_back(e);
  return out;
}

uint64_t MemoryLedger::total() const {
  std::lock_guard lock(mutex_);
  return total_;
}

uint64_t MemoryLedger::total_requested() const {
  std::lock_guard lock(mutex_);
  uint64_t sum = 0;
  for (const auto& [id, e] : live_) sum += e.requested;
  return sum;
}

std::map<std::string, uint64_t> MemoryLedger::per_category() const {
  std::lock_guard lock(mutex_);
  std::map<std::string, uint64_t> out;
  for (const auto& [id, e] : live_) out[e.category] += e.bytes;
  return out;
}

uint64_t MemoryLedger::peak() const {
  std::lock_guard lock(mutex_);
  return peak_;
}

void MemoryLedger::reset_peak() {
  std::lock_guard lock(mutex_);
  peak_ = total_;
}

nlohmann::json MemoryLedger::to_json() const {
  std::lock_guard lock(mutex_);
  nlohmann::json entries = nlohmann::json::array();
  nlohmann::json cats = nlohmann::json::object();
  for (const auto& [id, e] : live_) {
    entries.push_back({{"name", e.name},
                       {"category", e.category},
                       {"format", e.format},
                       {"bytes", e.bytes},
                       {"requested", e.requested}});
    uint64_t prev = cats.contains(e.category) ? cats[e.category].get<uint64_t>() : 0;
    cats[e.category] = prev + e.bytes;
  }
  return {{"entries", entries}, {"per_category", cats}, {"total", total_}, {"peak", peak_}};
}

}  // namespace haze::gpu
