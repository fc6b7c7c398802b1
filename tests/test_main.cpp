// The main of every test binary. The suite runs on lavapipe ("llvmpipe") unless HAZE_TEST_DEVICE names
// another Vulkan device (an index as in `haze --list-devices`, or a substring of its name); the haze
// commands the command-line tests start inherit the choice through HAZE_DEVICE. Validation is on;
// the SPIR-V and Mesa caches live in the build folder unless the environment already names them.
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

int main(int argc, char** argv) {
  const char* device = std::getenv("HAZE_TEST_DEVICE");
  ::setenv("HAZE_DEVICE", device && *device ? device : "llvmpipe", 1);
  ::setenv("HAZE_VALIDATION", "1", 0);  // on unless the environment says otherwise (scripts/fuzz.sh)
  ::setenv("HAZE_SHADER_CACHE", HAZE_TEST_BUILD_DIR "/shader-cache", 0);
  ::setenv("MESA_SHADER_CACHE_DIR", HAZE_TEST_BUILD_DIR "/mesa-cache", 0);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
