// Scene-error assertions shared by the scene and animation tests.
#pragma once

#include <gtest/gtest.h>

#include <functional>
#include <initializer_list>
#include <string>

#include "scene/scene.hpp"

namespace haze::test {

// Runs f, expects a scene::Error whose one-line message contains every piece; returns the message.
inline std::string expect_error(const std::function<void()>& f, std::initializer_list<std::string> pieces) {
  try {
    f();
  } catch (const scene::Error& e) {
    std::string msg = e.what();
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "message is not one line: " << msg;
    for (const auto& p : pieces) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
    return msg;
  }
  ADD_FAILURE() << "no haze::scene::Error thrown";
  return {};
}

// Reads j as scene.json, expects the error expect_error describes.
inline std::string read_error(const nlohmann::json& j, std::initializer_list<std::string> pieces) {
  return expect_error([&] { scene::from_json(j, "scene.json", ""); }, pieces);
}

}  // namespace haze::test
