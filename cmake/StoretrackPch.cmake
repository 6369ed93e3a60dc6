# One precompiled header for the project's own libraries and programs (Eigen, nlohmann-json, the
# standard library), the way storetrack_test_pch serves the tests: parsed once per tree instead of
# once per source. Measured on 2026-12-01, GCC 12 -O3, one compile each:
# host/pipeline/src/exposure_processor.cpp 33 s -> 28 s, estimation/pose/src/body_pose.cpp 27 s -> 23 s
# of CPU (docs/performance.md, "CI budget").
#
# storetrack_apply_pch() runs after every folder is added and gives the header to each library
# and executable that compiles with the project's flags (links storetrack_warnings: GCC refuses a
# header built with other flags, -Winvalid-pch, an error in CI) and sets none of its own
# (estimation/centroid's -fopenmp-simd, the fuzzers' instrumentation, -fPIC for code that goes
# into a shared object): those, and the tests (their own header), compile as before. Options
# every target inherits from the top directory are the header's too: the sanitizer tree's
# -fsanitize flags once kept all of its targets from it (0 of 34).
option(STORETRACK_PCH "Precompile Eigen + nlohmann-json once for the libraries and programs" ON)

function(storetrack_collect_targets out dir)
  get_property(targets DIRECTORY ${dir} PROPERTY BUILDSYSTEM_TARGETS)
  get_property(subdirs DIRECTORY ${dir} PROPERTY SUBDIRECTORIES)
  foreach(sub IN LISTS subdirs)
    storetrack_collect_targets(below ${sub})
    list(APPEND targets ${below})
  endforeach()
  set(${out} ${targets} PARENT_SCOPE)
endfunction()

function(storetrack_pch_wanted target out)
  set(${out} FALSE PARENT_SCOPE)
  get_target_property(type ${target} TYPE)
  if(NOT type MATCHES "^(STATIC_LIBRARY|OBJECT_LIBRARY|EXECUTABLE)$" OR target MATCHES "^fuzz_"
     OR target MATCHES "_pch$")
    return()
  endif()
  foreach(property PRECOMPILE_HEADERS PRECOMPILE_HEADERS_REUSE_FROM POSITION_INDEPENDENT_CODE)
    get_target_property(value ${target} ${property})
    if(value)
      return()
    endif()
  endforeach()
  # Options every target inherits from the top directory (the sanitizer flags) are the
  # header's own too; only a target's own options set it apart.
  get_target_property(options ${target} COMPILE_OPTIONS)
  get_directory_property(tree_options DIRECTORY ${PROJECT_SOURCE_DIR} COMPILE_OPTIONS)
  if(options AND NOT "${options}" STREQUAL "${tree_options}")
    return()
  endif()
  get_target_property(links ${target} LINK_LIBRARIES)
  if(NOT "storetrack_warnings" IN_LIST links)
    return()
  endif()
  set(${out} TRUE PARENT_SCOPE)
endfunction()

function(storetrack_apply_pch)
  if(NOT STORETRACK_PCH)
    return()
  endif()
  file(WRITE ${PROJECT_BINARY_DIR}/storetrack_pch.cpp "// the library PCH's own source\n")
  add_library(storetrack_pch STATIC ${PROJECT_BINARY_DIR}/storetrack_pch.cpp)
  target_link_libraries(storetrack_pch PRIVATE Eigen3::Eigen nlohmann_json::nlohmann_json
                                               storetrack_warnings)
  target_precompile_headers(storetrack_pch PRIVATE
    <Eigen/Core> <Eigen/Geometry> <Eigen/Cholesky> <Eigen/Eigenvalues> <Eigen/LU> <Eigen/SVD>
    <nlohmann/json.hpp>
    <algorithm> <array> <cmath> <cstdint> <cstring> <map> <memory> <optional> <random> <span>
    <string> <vector>)
  storetrack_collect_targets(targets ${PROJECT_SOURCE_DIR})
  set(count 0)
  foreach(target IN LISTS targets)
    storetrack_pch_wanted(${target} wanted)
    if(wanted)
      target_precompile_headers(${target} REUSE_FROM storetrack_pch)
      # The header's include paths, for a compiler that cannot use the precompiled form.
      target_link_libraries(${target} PRIVATE Eigen3::Eigen nlohmann_json::nlohmann_json)
      math(EXPR count "${count} + 1")
    endif()
  endforeach()
  message(STATUS "precompiled header (Eigen, nlohmann-json): ${count} targets")
endfunction()
