# Warnings for project targets only (not for Debian's headers, which are SYSTEM includes).
add_library(storetrack_warnings INTERFACE)
target_compile_options(storetrack_warnings INTERFACE
  -Wall -Wextra -Wpedantic -Wshadow=local -Wnon-virtual-dtor -Wcast-align -Wformat=2
  -Wimplicit-fallthrough)
if(STORETRACK_WERROR)
  target_compile_options(storetrack_warnings INTERFACE -Werror)
endif()

if(STORETRACK_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=all)
  add_link_options(-fsanitize=address,undefined)
endif()
