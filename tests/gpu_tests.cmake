# gpu_test: the GPU layer on lavapipe with validation on. Included from tests/CMakeLists.txt.
set(GPU_TEST_SPV ${CMAKE_CURRENT_BINARY_DIR}/gpu_test_add.spv)
add_custom_command(
  OUTPUT ${GPU_TEST_SPV}
  COMMAND ${GLSLANG_VALIDATOR} -V --target-env vulkan1.3 -o ${GPU_TEST_SPV}
          ${CMAKE_CURRENT_LIST_DIR}/shaders/gpu_test_add.comp
  DEPENDS ${CMAKE_CURRENT_LIST_DIR}/shaders/gpu_test_add.comp
  COMMENT "GLSL tests/shaders/gpu_test_add.comp"
  VERBATIM)

add_executable(gpu_test ${CMAKE_CURRENT_LIST_DIR}/gpu_test.cpp ${GPU_TEST_SPV})
target_link_libraries(gpu_test PRIVATE haze_gpu GTest::gtest_main)
target_compile_definitions(gpu_test PRIVATE GPU_TEST_SPV="${GPU_TEST_SPV}")

# One process for all cases: the Context and pipelines are created once (see DESIGN.md section 8).
add_test(NAME gpu_test COMMAND gpu_test)
file(GLOB GPU_TEST_LVP_ICD /usr/share/vulkan/icd.d/lvp_icd*.json)
set(GPU_TEST_ENV HAZE_VALIDATION=1 MESA_SHADER_CACHE_DIR=${CMAKE_BINARY_DIR}/mesa-cache)
if(GPU_TEST_LVP_ICD)
  list(GET GPU_TEST_LVP_ICD 0 GPU_TEST_LVP_ICD)
  list(APPEND GPU_TEST_ENV VK_DRIVER_FILES=${GPU_TEST_LVP_ICD})
endif()
set_tests_properties(gpu_test PROPERTIES ENVIRONMENT "${GPU_TEST_ENV}" TIMEOUT 120)
