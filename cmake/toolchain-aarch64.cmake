# Cross build of common/ + firmware/ for the camera unit (aarch64, Debian bookworm multiarch).
# Compiler: Debian's g++-aarch64-linux-gnu. Libraries: the arm64 -dev packages installed side by
# side with the native ones (libgpiod-dev:arm64, libmodbus-dev:arm64, libgtest-dev:arm64);
# header-only dependencies (Eigen, nlohmann-json, CLI11) are architecture-independent.
# Tests run under qemu-user through CMAKE_CROSSCOMPILING_EMULATOR.
#   cmake -S . -B build-aarch64 -G Ninja -DCMAKE_TOOLCHAIN_FILE=cmake/toolchain-aarch64.cmake \
#         -DSTORETRACK_FIRMWARE_ONLY=ON -DSTORETRACK_BENCHMARKS=OFF
# (tools/cross-build-aarch64.sh does this, builds, and runs the tests.)
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(STORETRACK_CROSS_TRIPLE aarch64-linux-gnu)

set(CMAKE_C_COMPILER ${STORETRACK_CROSS_TRIPLE}-gcc)
set(CMAKE_CXX_COMPILER ${STORETRACK_CROSS_TRIPLE}-g++)

# Debian multiarch: arm64 libraries live in /usr/lib/aarch64-linux-gnu, headers in /usr/include
# (shared) and /usr/aarch64-linux-gnu/include (libc, kernel UAPI). Never pick the amd64 ones.
set(CMAKE_LIBRARY_ARCHITECTURE ${STORETRACK_CROSS_TRIPLE})
list(APPEND CMAKE_IGNORE_PATH /usr/lib/x86_64-linux-gnu /lib/x86_64-linux-gnu
     /usr/lib/x86_64-linux-gnu/cmake /usr/lib/x86_64-linux-gnu/pkgconfig)
set(ENV{PKG_CONFIG_LIBDIR} "/usr/lib/${STORETRACK_CROSS_TRIPLE}/pkgconfig:/usr/share/pkgconfig")
set(ENV{PKG_CONFIG_PATH} "")

# Run target binaries (tests, gtest discovery) with qemu-user. The loader and libc must come from
# one glibc build. The arm64 -dev packages pull in multiarch libc6:arm64, whose loader is
# /lib/ld-linux-aarch64.so.1: use it with no -L. `-L /usr/aarch64-linux-gnu` would take the
# cross package's older loader (libc6-arm64-cross) while the libraries' search path still finds
# libc6:arm64's newer libc.so.6 in /lib/aarch64-linux-gnu; that mismatched pair hangs in the
# first pthread_create (seen with 2.36-8cross1 against 2.36-9+deb12u14). -L only without
# multiarch libc6:arm64 and libstdc++6:arm64 (tools/install-deps.sh --cross installs both).
find_program(STORETRACK_QEMU_AARCH64 NAMES qemu-aarch64-static qemu-aarch64 REQUIRED)
if(EXISTS /lib/ld-linux-aarch64.so.1 AND EXISTS /lib/${STORETRACK_CROSS_TRIPLE}/libc.so.6
   AND EXISTS /usr/lib/${STORETRACK_CROSS_TRIPLE}/libstdc++.so.6)
  set(CMAKE_CROSSCOMPILING_EMULATOR ${STORETRACK_QEMU_AARCH64})
else()
  set(CMAKE_CROSSCOMPILING_EMULATOR ${STORETRACK_QEMU_AARCH64} -L /usr/${STORETRACK_CROSS_TRIPLE})
endif()
