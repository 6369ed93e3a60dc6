# Warnings for project targets only (not for Debian's headers, which are SYSTEM includes).
add_library(storetrack_warnings INTERFACE)
target_compile_options(storetrack_warnings INTERFACE
  -Wall -Wextra -Wpedantic -Wnon-virtual-dtor -Wcast-align -Wformat=2 -Wimplicit-fallthrough
  $<$<CXX_COMPILER_ID:GNU>:-Wshadow=local>)
if(STORETRACK_WERROR)
  target_compile_options(storetrack_warnings INTERFACE -Werror)
endif()

if(STORETRACK_SANITIZE)
  # -g1 (line tables) after the build type's -g: the sanitizer reports' stack traces need file and
  # line only, and full debug info of the Eigen-heavy sources is about a third of their compile
  # time. The optimisation level stays the build type's, so its diagnostics are the same.
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all
                      $<$<OR:$<CONFIG:RelWithDebInfo>,$<CONFIG:Debug>>:-g1>)
  add_link_options(-fsanitize=address,undefined)
endif()
