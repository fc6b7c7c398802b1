// A bound on what reading one file may allocate. OpenVDB trusts the counts and lengths it reads from a
// .vdb: a corrupt one (a name length of 0xffffffff, a metadata count of 4 billion) asks for gigabytes, or
// for millions of small blocks, before anything can check it. While an AllocationBudget lives, an allocation
// of this thread larger than `single` bytes, or one that brings its total above `total`, throws
// std::bad_alloc, which the reader turns into a one-line "corrupt file" error.
#pragma once

#include <cstdint>

namespace haze::vdb {

class AllocationBudget {
 public:
  AllocationBudget(uint64_t single, uint64_t total);
  ~AllocationBudget();
  AllocationBudget(const AllocationBudget&) = delete;
  AllocationBudget& operator=(const AllocationBudget&) = delete;

  uint64_t refused() const { return refused_; }  // the size of the refused allocation (0: none so far)
  bool total_reached() const { return total_reached_; }
  uint64_t single() const { return single_; }
  uint64_t total() const { return total_; }

  // Called by operator new (vdb/alloc_budget.cpp) for this thread's budget, if any; false refuses.
  static bool admit(uint64_t bytes);

 private:
  uint64_t single_, total_, used_ = 0, refused_ = 0;
  bool total_reached_ = false;
  AllocationBudget* outer_;
};

}  // namespace haze::vdb
