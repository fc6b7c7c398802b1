#include "vdb/alloc_budget.hpp"

#include <cstdlib>
#include <new>

namespace haze::vdb {
namespace {

thread_local AllocationBudget* current = nullptr;

}  // namespace

AllocationBudget::AllocationBudget(uint64_t single, uint64_t total)
    : single_(single), total_(total), outer_(current) {
  current = this;
}

AllocationBudget::~AllocationBudget() {
  current = outer_;
}

bool AllocationBudget::admit(uint64_t bytes) {
  AllocationBudget* b = current;
  if (!b) return true;
  if (bytes > b->single_ || b->used_ + bytes > b->total_) {
    b->refused_ = bytes;
    b->total_reached_ = bytes <= b->single_;
    return false;
  }
  b->used_ += bytes;
  return true;
}

}  // namespace haze::vdb

// The process's operator new: malloc, within the current thread's AllocationBudget when one lives. The
// other forms (new[], nothrow, sized and aligned deletes) of the standard library forward to this one or
// free what malloc returned.
void* operator new(std::size_t n) {
  if (!haze::vdb::AllocationBudget::admit(n)) throw std::bad_alloc();
  for (;;) {
    if (void* p = std::malloc(n ? n : 1)) return p;
    std::new_handler h = std::get_new_handler();
    if (!h) throw std::bad_alloc();
    h();
  }
}

void operator delete(void* p) noexcept {
  std::free(p);
}

void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}
