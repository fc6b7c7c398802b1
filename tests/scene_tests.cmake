# Included by tests/CMakeLists.txt.
add_executable(scene_test ${CMAKE_CURRENT_LIST_DIR}/scene_test.cpp)
target_link_libraries(scene_test PRIVATE haze_scene GTest::gtest_main)
# The docs test checks that docs/scene-format.md mentions every parameter.
target_compile_definitions(scene_test PRIVATE HAZE_SCENE_FORMAT_MD="${CMAKE_CURRENT_LIST_DIR}/../docs/scene-format.md")
include(GoogleTest)
gtest_discover_tests(scene_test PROPERTIES TIMEOUT 60)

# Keyframed animation and VDB sequences (scene/animation.hpp); also evaluates the animated doc examples.
add_executable(animation_test ${CMAKE_CURRENT_LIST_DIR}/animation_test.cpp)
target_link_libraries(animation_test PRIVATE haze_scene GTest::gtest_main)
target_compile_definitions(animation_test PRIVATE HAZE_SCENE_FORMAT_MD="${CMAKE_CURRENT_LIST_DIR}/../docs/scene-format.md")
gtest_discover_tests(animation_test PROPERTIES TIMEOUT 60)
