#!/usr/bin/env bash
# Installs everything storetrack needs from Debian bookworm (and nothing from anywhere else).
# linuxptp: ptp4l for the clock test (tests/firmware/clock, two namespaces over a veth pair).
# libcpp-httplib-dev: the live page's HTTP server (host/live); chromium: its browser test
# (tests/host/live, driven by playwright-core from npm with the machine's Node.js).
# Idempotent: exits at once when every package is already present.
#   tools/install-deps.sh            build + test dependencies (host and unit, native)
#   tools/install-deps.sh --cross    also the aarch64 cross toolchain and arm64 -dev packages
#   tools/install-deps.sh --rig      also what the real-driver VM rig needs (qemu, busybox, ...)
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive

PKGS=(
  build-essential cmake ninja-build ccache pkg-config git python3 python3-yaml
  libeigen3-dev libopencv-dev libopencv-contrib-dev libceres-dev libgpiod-dev gpiod libmodbus-dev linux-libc-dev
  libgtest-dev libgmock-dev libbenchmark-dev libsep-dev
  libcli11-dev libspdlog-dev libfmt-dev nlohmann-json3-dev libyaml-cpp-dev libpng-dev libssl-dev
  python3-matplotlib python3-numpy clang-format clang libclang-rt-14-dev tshark mbpoll python3-pymodbus can-utils v4l-utils
  iproute2 linuxptp libcpp-httplib-dev chromium
)
CROSS_PKGS=(g++-aarch64-linux-gnu qemu-user-static libc6:arm64 libstdc++6:arm64 libgpiod-dev:arm64 libmodbus-dev:arm64 libgtest-dev:arm64)
RIG_PKGS=(qemu-system-x86 busybox-static cpio kmod xz-utils gcc-12 make libelf1 libssl3 bc flex bison)

want=("${PKGS[@]}")
for a in "$@"; do
  case "$a" in
    --cross) want+=("${CROSS_PKGS[@]}") ;;
    --rig) want+=("${RIG_PKGS[@]}") ;;
    --all) want+=("${CROSS_PKGS[@]}" "${RIG_PKGS[@]}") ;;
    *) echo "install-deps: unknown option '$a' (use --cross, --rig, --all)" >&2; exit 2 ;;
  esac
done

# `dpkg -s libgpiod-dev` fails as "ambiguous" once libgpiod-dev:arm64 is installed too, so
# compare against dpkg's list of installed names (native ones also without their ":arch").
all_installed() {
  dpkg-query -W -f='${binary:Package} ${db:Status-Abbrev}\n' 2>/dev/null |
    awk -v native=":$(dpkg --print-architecture)" -v want="$*" '
      $2 == "ii" { have[$1] = 1; n = $1; sub(native "$", "", n); have[n] = 1 }
      END { k = split(want, w, " "); for (i = 1; i <= k; i++) if (!(w[i] in have)) exit 1 }'
}
if all_installed "${want[@]}"; then exit 0; fi
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
if printf '%s\n' "${want[@]}" | grep -q ':arm64'; then
  dpkg --print-foreign-architectures | grep -qx arm64 || $SUDO dpkg --add-architecture arm64
fi
echo "install-deps: installing missing Debian packages (one-time)..." >&2
# tshark asks whether non-root users may capture; answer no, non-interactively
echo "wireshark-common wireshark-common/install-setuid boolean false" | $SUDO debconf-set-selections
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${want[@]}" >/dev/null
