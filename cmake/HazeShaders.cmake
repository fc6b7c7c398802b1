# GLSL -> SPIR-V at build time, one .spv per feature variant.
#   haze_shader(SOURCE volume/trace.comp FEATURES HETERO EMISSION ... [REQUIRES EMISSION:HETERO ...])
# compiles every subset of FEATURES as defines HAZE_<F>=1; the variant's file name carries a bit mask
# in FEATURES order (trace.comp.5.spv = features 0 and 2). A:B in REQUIRES skips the subsets that have A
# without B, A:B|C those that have A without B or C (variants no scene can ask for). Includes are tracked with --depfile.
set(HAZE_SPV_DIR ${CMAKE_BINARY_DIR}/spv)
set_property(GLOBAL PROPERTY HAZE_SPV_FILES "")

function(haze_shader)
  cmake_parse_arguments(S "" "SOURCE" "FEATURES;REQUIRES" ${ARGN})
  list(LENGTH S_FEATURES n)
  math(EXPR count "1 << ${n}")
  math(EXPR last "${count} - 1")
  get_filename_component(dir ${S_SOURCE} DIRECTORY)
  get_filename_component(name ${S_SOURCE} NAME)
  set(src ${CMAKE_SOURCE_DIR}/shaders/${S_SOURCE})
  foreach(mask RANGE 0 ${last})
    set(skip FALSE)
    foreach(req IN LISTS S_REQUIRES)
      string(REPLACE ":" ";" pair ${req})
      list(GET pair 0 a)
      list(GET pair 1 alternatives)
      list(FIND S_FEATURES ${a} ia)
      math(EXPR has_a "(${mask} >> ${ia}) & 1")
      string(REPLACE "|" ";" alternatives ${alternatives})
      set(has_b 0)
      foreach(b IN LISTS alternatives)
        list(FIND S_FEATURES ${b} ib)
        math(EXPR bit "(${mask} >> ${ib}) & 1")
        if(bit)
          set(has_b 1)
        endif()
      endforeach()
      if(has_a AND NOT has_b)
        set(skip TRUE)
      endif()
    endforeach()
    if(skip)
      continue()
    endif()
    set(defines "")
    set(i 0)
    foreach(f IN LISTS S_FEATURES)
      math(EXPR bit "(${mask} >> ${i}) & 1")
      if(bit)
        list(APPEND defines "-DHAZE_${f}=1")
      endif()
      math(EXPR i "${i} + 1")
    endforeach()
    set(out ${HAZE_SPV_DIR}/${dir}/${name}.${mask}.spv)
    add_custom_command(
      OUTPUT ${out}
      COMMAND ${CMAKE_COMMAND} -E make_directory ${HAZE_SPV_DIR}/${dir}
      COMMAND ${GLSLANG_VALIDATOR} -V --target-env vulkan1.3 -g0 -Os
              -I${CMAKE_SOURCE_DIR}/shaders -I/usr/include ${defines}
              --depfile ${out}.d -o ${out} ${src}
      DEPENDS ${src}
      DEPFILE ${out}.d
      COMMENT "GLSL ${S_SOURCE} [${mask}]"
      VERBATIM)
    set_property(GLOBAL APPEND PROPERTY HAZE_SPV_FILES ${out})
  endforeach()
endfunction()
