// Runs the haze binary (HAZE_BIN) as a user would, for the command-line tests.
#pragma once

#include <fmt/format.h>
#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <string>

namespace haze::test {

struct Result {
  int code;         // exit status, -1 when killed
  std::string out;  // stdout and stderr together
};

// A whole shell command line (a wrapper around haze, an environment), stdout and stderr together.
inline Result run_command(const std::string& command) {
  std::string cmd = command + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  std::string out;
  std::array<char, 4096> buf{};
  while (size_t n = fread(buf.data(), 1, buf.size(), p)) out.append(buf.data(), n);
  int status = pclose(p);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, out};
}

inline Result run(const std::string& args) {
  return run_command(fmt::format("{} {}", HAZE_BIN, args));
}

}  // namespace haze::test
