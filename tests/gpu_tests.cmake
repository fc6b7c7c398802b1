# gpu_test: the GPU layer on lavapipe with validation on. Included from tests/CMakeLists.txt.
# Test shaders: tests/shaders/<name>.comp -> <build>/<name>.spv.
set(GPU_TEST_SPVS)
foreach(name gpu_test_add gpu_test_image)
  set(spv ${CMAKE_CURRENT_BINARY_DIR}/${name}.spv)
  add_custom_command(
    OUTPUT ${spv}
    COMMAND ${GLSLANG_VALIDATOR} -V --target-env vulkan1.3 -o ${spv}
            ${CMAKE_CURRENT_LIST_DIR}/shaders/${name}.comp
    DEPENDS ${CMAKE_CURRENT_LIST_DIR}/shaders/${name}.comp
    COMMENT "GLSL tests/shaders/${name}.comp"
    VERBATIM)
  list(APPEND GPU_TEST_SPVS ${spv})
endforeach()
set(GPU_TEST_SPV ${CMAKE_CURRENT_BINARY_DIR}/gpu_test_add.spv)
set(GPU_TEST_IMAGE_SPV ${CMAKE_CURRENT_BINARY_DIR}/gpu_test_image.spv)

add_executable(gpu_test ${CMAKE_CURRENT_LIST_DIR}/gpu_test.cpp ${GPU_TEST_SPVS})
target_link_libraries(gpu_test PRIVATE haze_gpu glm::glm GTest::gtest_main)
target_compile_definitions(gpu_test PRIVATE GPU_TEST_SPV="${GPU_TEST_SPV}"
                                            GPU_TEST_IMAGE_SPV="${GPU_TEST_IMAGE_SPV}")

# One process for all cases: the Context and pipelines are created once (see DESIGN.md section 8).
add_test(NAME gpu_test COMMAND gpu_test)
file(GLOB GPU_TEST_LVP_ICD /usr/share/vulkan/icd.d/lvp_icd*.json)
set(GPU_TEST_ENV HAZE_VALIDATION=1 MESA_SHADER_CACHE_DIR=${CMAKE_BINARY_DIR}/mesa-cache)
if(GPU_TEST_LVP_ICD)
  list(GET GPU_TEST_LVP_ICD 0 GPU_TEST_LVP_ICD)
  list(APPEND GPU_TEST_ENV VK_DRIVER_FILES=${GPU_TEST_LVP_ICD})
endif()
set_tests_properties(gpu_test PROPERTIES ENVIRONMENT "${GPU_TEST_ENV}" TIMEOUT 120)
