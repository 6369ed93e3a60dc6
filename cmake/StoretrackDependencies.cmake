# All dependencies come from Debian bookworm packages (tools/install-deps.sh installs them).
find_package(Threads REQUIRED)
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(nlohmann_json 3.10 REQUIRED)
find_package(PkgConfig REQUIRED)
pkg_check_modules(GPIOD REQUIRED IMPORTED_TARGET libgpiod>=1.6)
pkg_check_modules(MODBUS REQUIRED IMPORTED_TARGET libmodbus>=3.1.6)
find_package(Python3 REQUIRED COMPONENTS Interpreter)
find_package(GTest REQUIRED)

if(NOT STORETRACK_FIRMWARE_ONLY)
  find_package(OpenCV 4.6 REQUIRED COMPONENTS core imgproc imgcodecs calib3d aruco)
  find_package(Ceres 2.1 REQUIRED)
  find_package(CLI11 REQUIRED)
  find_package(fmt REQUIRED)
  find_package(spdlog REQUIRED)
  # SHA-256 of the recorded inputs (common/digest): libcrypto, the FIPS-validated implementation
  # Debian ships (libssl-dev), not a hand-written one.
  find_package(OpenSSL 3 REQUIRED COMPONENTS Crypto)
  if(STORETRACK_BENCHMARKS)
    find_package(benchmark REQUIRED)
    pkg_check_modules(SEP IMPORTED_TARGET sep)
    if(NOT SEP_FOUND)
      # Debian's libsep-dev ships no .pc file: find it by hand.
      find_path(SEP_INCLUDE_DIR sep.h REQUIRED)
      find_library(SEP_LIBRARY sep REQUIRED)
      add_library(PkgConfig::SEP INTERFACE IMPORTED)
      target_include_directories(PkgConfig::SEP INTERFACE ${SEP_INCLUDE_DIR})
      target_link_libraries(PkgConfig::SEP INTERFACE ${SEP_LIBRARY})
    endif()
  endif()
else()
  # The cross build still wants CLI11 (header-only) for storetrack-unit when present.
  find_package(CLI11 QUIET)
endif()

# storetrack_test(NAME name SOURCES ... LIBS ... [LABELS ...] [TIMEOUT s] [COST s]): a
# GoogleTest executable, registered with ctest (one ctest entry per executable keeps the 2-core
# CI quick). COST: its seconds in the sanitizer tree, for ctest's ordering.
#
# Every one of them reuses ONE precompiled header (GoogleTest, Eigen, the standard library:
# storetrack_test_pch below), parsed once per tree instead of once per test source
# (tests/host/match/test_mark_matcher.cpp: 21 s of CPU without, 15 s with). The tests' own
# flags match the header's (same tree, same warnings, GoogleTest's definitions), which GCC
# checks: an unusable header is a -Winvalid-pch warning, so an error in CI.
#
# A test whose name matches STORETRACK_TESTS_NOT_BUILT (a regex; the aarch64 cross build leaves
# the simulator's tests to the native build) stays a target, so the rules that follow it still
# apply, but is neither built by `all` nor registered with ctest; the configure log lists it.
set(STORETRACK_TESTS_NOT_BUILT "" CACHE STRING "Regex of GoogleTest executables not to build")
option(STORETRACK_TEST_PCH "Precompile GoogleTest + Eigen once for all test executables" ON)
# The sanitizer tree compiles the tests' own sources at -O0 (after, so in place of, the tree's
# -O1): the code under test is in the libraries, still -O1, and a test source compiles in about
# half the time (clang ASan + UBSan, tests/estimation/pose/test_body_pose.cpp: 49 s -> 28 s of CPU).
# ASan and UBSan see at least as much at -O0. The tests' PCH gets the same, so that it matches.
# A test marked LONG_RUNNING (its own code loops: Monte Carlo draws, image synthesis, synthetic
# calibrations) stays at -O1, without the shared PCH: at -O0 test_uncertainty_honesty_static ran
# over 6 min, not 80 s. Not only the test's own code: the linker keeps one copy of each inline
# function (Eigen's products), often the -O0 test object's, so the library's loops ran at -O0
# too (test_calib under ASan: 140 s at -O0, 17 s at -O1). A PCH of their own at -O1 was tried:
# no gain (test_calib's sources spend their time in code generation, not parsing).
function(storetrack_sanitizer_test_flags target)
  if(STORETRACK_SANITIZE)
    target_compile_options(${target} PRIVATE "$<$<CONFIG:Release,RelWithDebInfo,MinSizeRel>:-O0>")
  endif()
endfunction()

function(storetrack_test_pch)
  if(NOT STORETRACK_TEST_PCH OR TARGET storetrack_test_pch)
    return()
  endif()
  if(NOT EXISTS ${PROJECT_BINARY_DIR}/storetrack_test_pch.cpp)
    file(WRITE ${PROJECT_BINARY_DIR}/storetrack_test_pch.cpp "// the test PCH's own source\n")
  endif()
  add_library(storetrack_test_pch STATIC ${PROJECT_BINARY_DIR}/storetrack_test_pch.cpp)
  target_link_libraries(storetrack_test_pch PRIVATE GTest::gtest Eigen3::Eigen storetrack_warnings)
  storetrack_sanitizer_test_flags(storetrack_test_pch)
  target_precompile_headers(storetrack_test_pch PRIVATE
    <gtest/gtest.h> <Eigen/Dense> <Eigen/Geometry>
    <algorithm> <array> <cmath> <cstdint> <cstring> <filesystem> <fstream> <map> <memory>
    <optional> <random> <span> <sstream> <string> <vector>)
endfunction()
function(storetrack_test)
  cmake_parse_arguments(T "LONG_RUNNING" "NAME;TIMEOUT;COST" "SOURCES;LIBS;LABELS;SPLIT_OUT" ${ARGN})
  add_executable(${T_NAME} ${T_SOURCES})
  target_link_libraries(${T_NAME} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main storetrack_warnings)
  if(STORETRACK_SANITIZE)
    # Monte Carlo and timing tests size their runs down (a smoke run of the code under the
    # sanitizers) and leave wall-clock bounds to the Release stage.
    target_compile_definitions(${T_NAME} PRIVATE STORETRACK_SANITIZE=1)
  endif()
  if(T_LONG_RUNNING AND STORETRACK_SANITIZE)
    # the tree's -O1; not the shared PCH, which is -O0 there
  else()
    storetrack_sanitizer_test_flags(${T_NAME})
    if(STORETRACK_TEST_PCH)
      storetrack_test_pch()
      target_precompile_headers(${T_NAME} REUSE_FROM storetrack_test_pch)
    endif()
  endif()
  if(STORETRACK_TESTS_NOT_BUILT AND T_NAME MATCHES "${STORETRACK_TESTS_NOT_BUILT}")
    set_target_properties(${T_NAME} PROPERTIES EXCLUDE_FROM_ALL TRUE)
    message(STATUS "test not built in this tree: ${T_NAME}")
    return()
  endif()
  # SPLIT_OUT: GoogleTest cases run as ctest entries of their own (NAME.Suite.Case), so that
  # ctest -j runs a program's longest case beside the rest of it instead of after it.
  set(ctest_names ${T_NAME})
  if(T_SPLIT_OUT)
    list(JOIN T_SPLIT_OUT ":" split_filter)
    add_test(NAME ${T_NAME} COMMAND ${T_NAME} --gtest_filter=-${split_filter})
    foreach(test_case ${T_SPLIT_OUT})
      add_test(NAME ${T_NAME}.${test_case} COMMAND ${T_NAME} --gtest_filter=${test_case})
      list(APPEND ctest_names ${T_NAME}.${test_case})
    endforeach()
  else()
    add_test(NAME ${T_NAME} COMMAND ${T_NAME})
  endif()
  if(NOT T_TIMEOUT)
    set(T_TIMEOUT 300)
  endif()
  if(CMAKE_CROSSCOMPILING_EMULATOR)
    # Under qemu-user (aarch64 tests on the x86 CI machine) code runs ~10x slower.
    math(EXPR T_TIMEOUT "${T_TIMEOUT} * 8")
  endif()
  set_tests_properties(${ctest_names} PROPERTIES TIMEOUT ${T_TIMEOUT} LABELS "${T_LABELS}")
  if(T_COST)
    # ctest -j starts the costliest first; a fresh tree has no timing history (Testing/), so
    # without it the longest tests started last and ran alone at the end.
    set_tests_properties(${ctest_names} PROPERTIES COST ${T_COST})
  endif()
endfunction()
