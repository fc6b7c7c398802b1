# Included by tests/CMakeLists.txt. surfaces_test: meshes, primitives, BVH invariants on the CPU, and the
# shaders' BVH traversal on lavapipe against Embree. One process: the Context and pipelines once.
add_executable(surfaces_test ${CMAKE_CURRENT_LIST_DIR}/surfaces_test.cpp)
target_link_libraries(surfaces_test PRIVATE haze_surfaces haze_gpu GTest::gtest_main fmt::fmt stb)
add_test(NAME surfaces_test COMMAND surfaces_test)
set_tests_properties(surfaces_test PROPERTIES TIMEOUT 300 ENVIRONMENT "${HAZE_TEST_ENV}")
