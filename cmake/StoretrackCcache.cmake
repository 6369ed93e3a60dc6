# Compiler caching (Debian's ccache), for every build tree: the README's two commands, CI's
# stages and a developer's own trees share one cache (~/.cache/ccache, 10 GiB cap).
#
# CCACHE_BASEDIR = the checkout makes every path inside it relative in the hash, and
# CCACHE_NOHASHDIR keeps the compiler's working directory out of it, so a fresh clone in
# another folder (CI runs in one) hits what the developer's session compiled. Debug info then
# names the tree that first compiled an object; nothing else differs. A machine without ccache,
# or with -DSTORETRACK_CCACHE=OFF, compiles as before. Settings travel on the launcher's command
# line (not in the calling shell), so a plain `ninja -C build` hits the same cache.
if(NOT STORETRACK_CCACHE OR CMAKE_CXX_COMPILER_LAUNCHER)
  return()
endif()
find_program(STORETRACK_CCACHE_PROGRAM ccache)
if(NOT STORETRACK_CCACHE_PROGRAM)
  message(STATUS "ccache not found: compiling without a cache")
  return()
endif()
# The sloppiness is what ccache needs to cache compiles that use the tests' precompiled header
# (its manual, "Precompiled headers"); the header's own contents are still hashed.
set(storetrack_ccache_launcher env CCACHE_BASEDIR=${PROJECT_SOURCE_DIR} CCACHE_NOHASHDIR=true
    CCACHE_MAXSIZE=10G CCACHE_SLOPPINESS=pch_defines,time_macros,include_file_mtime,include_file_ctime
    ${STORETRACK_CCACHE_PROGRAM})
set(CMAKE_C_COMPILER_LAUNCHER ${storetrack_ccache_launcher})
set(CMAKE_CXX_COMPILER_LAUNCHER ${storetrack_ccache_launcher})
message(STATUS "ccache: ${STORETRACK_CCACHE_PROGRAM} (base dir ${PROJECT_SOURCE_DIR})")
