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

# Run target binaries (tests, gtest discovery) with qemu-user; -L gives the arm64 loader + libc.
find_program(STORETRACK_QEMU_AARCH64 NAMES qemu-aarch64-static qemu-aarch64 REQUIRED)
set(CMAKE_CROSSCOMPILING_EMULATOR ${STORETRACK_QEMU_AARCH64} -L /usr/${STORETRACK_CROSS_TRIPLE})
