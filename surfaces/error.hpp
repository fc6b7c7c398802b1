#pragma once
// Errors of the surfaces part: one exception type whose text is one line naming the file or parameter.

#include <stdexcept>

namespace haze::surfaces {

struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace haze::surfaces
