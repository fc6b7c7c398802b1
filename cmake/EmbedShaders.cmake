# GLSL sources compiled into the binary, for the run-time shader compiler (gpu/shader_compiler.hpp).
#
#   haze_embed_shaders(<target> ROOT <dir> [GLOB <pattern>...] [FILES <key>=<path>...])
#
# adds a static library <target> holding one generated .cpp with every file under ROOT that matches a
# GLOB pattern (keyed by its path relative to ROOT: "volume/trace.comp") and every FILES entry (keyed
# <key>: "nanovdb/PNanoVDB.h"), as the table gpu/embedded_sources.hpp declares. The .cpp is written at
# build time by this same file run as a script (cmake -P), so editing an embedded file regenerates it;
# adding or removing one re-runs the configuration (CONFIGURE_DEPENDS).
#
# Each file becomes pieces of at most kPiece bytes, cut after a newline, each one C++ raw string
# literal (plus "\r" escapes outside the raw literal: a carriage return inside one is not portable, and
# PNanoVDB.h has CRLF line ends). The script refuses a file that holds the raw literal's delimiter.

if(NOT CMAKE_SCRIPT_MODE_FILE)
  set(HAZE_EMBED_SHADERS_SCRIPT ${CMAKE_CURRENT_LIST_FILE})

  function(haze_embed_shaders target)
    cmake_parse_arguments(E "" "ROOT" "GLOB;FILES" ${ARGN})
    if(NOT E_GLOB)
      set(E_GLOB *.comp *.glsl)
    endif()
    set(patterns "")
    foreach(g IN LISTS E_GLOB)
      list(APPEND patterns ${E_ROOT}/${g})
    endforeach()
    file(GLOB_RECURSE found LIST_DIRECTORIES false CONFIGURE_DEPENDS ${patterns})
    list(SORT found)
    set(manifest "")
    set(depends "")
    foreach(path IN LISTS found)
      file(RELATIVE_PATH key ${E_ROOT} ${path})
      string(APPEND manifest "${key}\n${path}\n")
      list(APPEND depends ${path})
    endforeach()
    foreach(entry IN LISTS E_FILES)
      string(FIND "${entry}" "=" eq)
      if(eq LESS 1)
        message(FATAL_ERROR "haze_embed_shaders: FILES entry '${entry}' is not <key>=<path>")
      endif()
      string(SUBSTRING "${entry}" 0 ${eq} key)
      math(EXPR rest "${eq} + 1")
      string(SUBSTRING "${entry}" ${rest} -1 path)
      if(NOT EXISTS ${path})
        message(FATAL_ERROR "haze_embed_shaders: ${path} (for '${key}') does not exist")
      endif()
      string(APPEND manifest "${key}\n${path}\n")
      list(APPEND depends ${path})
    endforeach()

    set(dir ${CMAKE_CURRENT_BINARY_DIR}/${target})
    set(list_file ${dir}/embedded_sources.list)
    set(out ${dir}/embedded_sources.cpp)
    file(CONFIGURE OUTPUT ${list_file} CONTENT "${manifest}" @ONLY)  # rewritten only when it changes
    add_custom_command(
      OUTPUT ${out}
      COMMAND ${CMAKE_COMMAND} -DLIST=${list_file} -DOUT=${out} -P ${HAZE_EMBED_SHADERS_SCRIPT}
      DEPENDS ${depends} ${list_file} ${HAZE_EMBED_SHADERS_SCRIPT}
      COMMENT "Embedding shader sources (${target})"
      VERBATIM)
    add_library(${target} STATIC ${out})
    cmake_path(GET CMAKE_CURRENT_FUNCTION_LIST_DIR PARENT_PATH root)
    target_include_directories(${target} PRIVATE ${root})  # gpu/embedded_sources.hpp
    target_compile_features(${target} PRIVATE cxx_std_20)
  endfunction()
  return()
endif()

# ---- script mode: cmake -DLIST=<manifest> -DOUT=<file.cpp> -P EmbedShaders.cmake ----
set(kPiece 32768)  # bytes per piece; a literal must stay < 64 KiB for portable compilers
set(kDelim "haze_glsl")

file(STRINGS ${LIST} lines)
list(LENGTH lines n)
math(EXPR odd "${n} % 2")
if(odd)
  message(FATAL_ERROR "EmbedShaders: malformed manifest ${LIST}")
endif()

set(body "")
set(table "")
set(index 0)
set(i 0)
while(i LESS n)
  list(GET lines ${i} key)
  math(EXPR j "${i} + 1")
  list(GET lines ${j} path)
  math(EXPR i "${i} + 2")

  # file(READ) drops a carriage return before a newline (and at the end of the file); put them back
  # when every newline had one, and check the bytes against the file's.
  file(READ ${path} text)
  file(READ ${path} want_hex HEX)
  string(HEX "${text}" got_hex)
  if(NOT got_hex STREQUAL want_hex)
    string(REPLACE "\n" "\r\n" text "${text}")
    string(HEX "${text}" got_hex)
    if(NOT got_hex STREQUAL want_hex)
      message(FATAL_ERROR "EmbedShaders: ${path} mixes LF and CRLF line ends (or ends with a carriage "
                          "return); cannot embed it byte for byte")
    endif()
  endif()
  string(FIND "${text}" ")${kDelim}\"" bad)
  if(NOT bad EQUAL -1)
    message(FATAL_ERROR "EmbedShaders: ${path} contains ')${kDelim}\"', the raw string delimiter; "
                        "change kDelim in ${CMAKE_CURRENT_LIST_FILE}")
  endif()
  string(LENGTH "${text}" size)

  set(pieces "")
  set(count 0)
  set(pos 0)
  while(pos LESS size)
    math(EXPR left "${size} - ${pos}")
    if(left GREATER kPiece)
      string(SUBSTRING "${text}" ${pos} ${kPiece} piece)
      string(FIND "${piece}" "\n" cut REVERSE)
      if(cut GREATER -1)
        math(EXPR len "${cut} + 1")
        string(SUBSTRING "${piece}" 0 ${len} piece)
      else()
        set(len ${kPiece})  # one very long line: cut anywhere
      endif()
    else()
      string(SUBSTRING "${text}" ${pos} -1 piece)
      set(len ${left})
    endif()
    math(EXPR pos "${pos} + ${len}")
    string(REPLACE "\r" ")${kDelim}\" \"\\r\" R\"${kDelim}(" piece "${piece}")
    string(APPEND pieces "    R\"${kDelim}(${piece})${kDelim}\",\n")
    math(EXPR count "${count} + 1")
  endwhile()
  if(count EQUAL 0)
    set(pieces "    \"\",\n")
    set(count 1)
  endif()

  string(APPEND body "// ${key}\nconst char* const file${index}[] = {\n${pieces}};\n\n")
  string(APPEND table "    {\"${key}\", file${index}, ${count}, ${size}},\n")
  math(EXPR index "${index} + 1")
endwhile()

file(WRITE ${OUT}.tmp
     "// Generated by cmake/EmbedShaders.cmake from ${LIST}; do not edit.\n"
     "#include \"gpu/embedded_sources.hpp\"\n\n"
     "namespace haze::gpu::embedded {\nnamespace {\n\n${body}}  // namespace\n\n"
     "const File kFiles[] = {\n${table}};\n"
     "const size_t kFileCount = ${index};\n\n"
     "}  // namespace haze::gpu::embedded\n")
file(RENAME ${OUT}.tmp ${OUT})
