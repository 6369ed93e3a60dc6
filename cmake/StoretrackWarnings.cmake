# Warnings for project targets only (not for Debian's headers, which are SYSTEM includes).
add_library(storetrack_warnings INTERFACE)
target_compile_options(storetrack_warnings INTERFACE
  -Wall -Wextra -Wpedantic -Wnon-virtual-dtor -Wcast-align -Wformat=2 -Wimplicit-fallthrough
  $<$<CXX_COMPILER_ID:GNU>:-Wshadow=local>)
if(STORETRACK_WERROR)
  target_compile_options(storetrack_warnings INTERFACE -Werror)
endif()

if(STORETRACK_SANITIZE)
  # Optimised sanitizer builds compile at -O1 -g1 (after, so in place of, the build type's -O and
  # -g): -O1 is ASan's own recommendation and, with UBSan instrumenting the Eigen-heavy sources,
  # a third less compile time than -O2 (common/sim body.cpp: 33 s against 51 s of CPU); line
  # tables are all the reports' stack traces need. Debug keeps -O0 -g.
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all
                      "$<$<CONFIG:Release,RelWithDebInfo,MinSizeRel>:-O1;-g1>")
  add_link_options(-fsanitize=address,undefined)
  # clang does not vectorise at -O1, so each `#pragma omp simd` loop (the centroider) reports
  # that it was not vectorised: true here and of no concern, not a warning to stop on.
  if(CMAKE_CXX_COMPILER_ID STREQUAL "Clang")
    add_compile_options("$<$<CONFIG:Release,RelWithDebInfo,MinSizeRel>:-Wno-pass-failed>")
  endif()
endif()

# A program no test of the sanitizer tree runs (a bench tool, the VM rig's drivers: the rig and
# the kill -9 run boot the Release tree's programs): left out of that tree's default target, so
# its stage does not compile it (150 s of CPU). `ninja <name>` there still builds it.
function(storetrack_not_in_sanitizer_stage target)
  if(STORETRACK_SANITIZE)
    set_target_properties(${target} PROPERTIES EXCLUDE_FROM_ALL ON)
  endif()
endfunction()

# Test support (the scene simulator: the truth generator, which production libraries never link)
# compiled in the sanitizer tree without ASan/UBSan and at -O2: the product code it feeds, the
# tests' own code and every library it links stay instrumented. clang supports uninstrumented
# objects in ASan/UBSan executables (they only lack the checks). Less to compile (simulator.cpp
# 20.7 s -> 10.3 s of CPU) and the tests that spend their time rendering boards and frames or
# drawing Monte Carlo truth run faster (docs/performance.md "CI budget"). Its own options keep it
# from the library PCH (built with -fsanitize), which clang refuses for a TU without it.
function(storetrack_uninstrumented_in_sanitizer_tree target)
  if(STORETRACK_SANITIZE)
    target_compile_options(${target} PRIVATE -fno-sanitize=address,undefined
                           "$<$<CONFIG:Release,RelWithDebInfo,MinSizeRel>:-O2>")
  endif()
endfunction()
