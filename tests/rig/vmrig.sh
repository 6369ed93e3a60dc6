#!/bin/bash
# vmrig.sh - run a command inside a QEMU VM booting Debian bookworm's own kernel, so tests reach
# REAL Linux drivers (vcan / CAN FD, gpio-sim, vivid) that this machine's kernel lacks.
#
#   tests/rig/vmrig.sh [--out DIR] [--prepare-only] ['command run inside the VM']
#
# The host root is shared read-only into the VM over virtio-9p with a tmpfs overlay on top, so
# the host's tools (can-utils, gpiod, v4l-utils) and the build tree's binaries run unchanged.
# DIR (default: a fresh dir under the cache) is shared writable at the same path: the command can
# leave logs and results there. The script exits with the command's exit status; 77 when the rig
# cannot start here (no qemu, not root, kernel packages not downloadable), 98/99 when the VM did
# not come up or did not report.
#
# Everything is cached under STORETRACK_VMRIG_DIR (default /var/tmp/storetrack-vmrig): the kernel
# .debs (apt-get download + dpkg -x; nothing is installed into /boot), the gpio-sim module built
# from Debian's linux-source-6.1 (Debian's kernel has CONFIG_GPIO_SIM unset), and the initramfs.
# A warm run costs one TCG boot (~10 s); a cold one adds the downloads and a ~5 s module build.
set -euo pipefail

SKIP=77
skip() { echo "vmrig: SKIPPED: $*" >&2; exit $SKIP; }
die() { echo "vmrig: ERROR: $*" >&2; exit 99; }
elapsed() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b-a}'; }

OUT=""; PREPARE_ONLY=0
while [ $# -gt 0 ]; do
  case "$1" in
    --out) OUT=$2; shift 2 ;;
    --prepare-only) PREPARE_ONLY=1; shift ;;
    -h|--help) sed -n '2,18p' "$0"; exit 0 ;;
    --) shift; break ;;
    *) break ;;
  esac
done
CMD=${1:-}
[ -n "$CMD" ] || [ $PREPARE_ONLY = 1 ] || { echo "usage: $0 [--out DIR] [--prepare-only] 'command'" >&2; exit 2; }

W=${STORETRACK_VMRIG_DIR:-/var/tmp/storetrack-vmrig}
HERE=$PWD

# --- 0. can the rig start here at all? ------------------------------------------------------
[ "$(id -u)" = 0 ] || skip "needs root (9p export of / and depmod/chroot in the guest); run as root"
command -v qemu-system-x86_64 >/dev/null || skip "qemu-system-x86_64 not found (tools/install-deps.sh --rig)"
# the initramfs has no libc: busybox must be Debian's static build
case "$(LC_ALL=C ldd /bin/busybox 2>&1 || true)" in
  *"not a dynamic"*|*"statically linked"*) ;;
  *) skip "static /bin/busybox missing (Debian busybox-static; tools/install-deps.sh --rig)" ;;
esac
for t in cpio gzip depmod modprobe make gcc-12 dpkg apt-get apt-cache; do
  command -v $t >/dev/null || skip "'$t' not found (tools/install-deps.sh --rig)"
done
case "$W" in *" "*) die "STORETRACK_VMRIG_DIR must not contain spaces" ;; esac
mkdir -p "$W/runs"
W=$(realpath "$W")

# --- 1. prepare (once; serialised between concurrent runs) ----------------------------------
# The VM's /init (busybox sh): mounts the 9p root + overlay, runs $OUTP/cmd, powers off.
write_init() {
  cat > "$1" <<'EOF'
#!/bin/sh
# storetrack vmrig init: paths come from the kernel command line (vmrig.out=, vmrig.mods=).
export PATH=/bin
mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t devtmpfs dev /dev
for a in $(cat /proc/cmdline); do
  case "$a" in vmrig.out=*) OUTP=${a#vmrig.out=} ;; vmrig.mods=*) MODS=${a#vmrig.mods=} ;; esac
done
for m in $(cat /mod/order); do insmod /mod/$m; done
O=trans=virtio,version=9p2000.L,msize=262144
mount -t 9p -o $O,ro,cache=loose hostroot /host && mount -t 9p -o $O,cache=none out /out ||
  { echo VMTEST_EXIT=98; poweroff -f; }
mount -t tmpfs -o size=768m tmp /ovl; mkdir /ovl/u /ovl/w
R=/newroot; mount -t overlay -o lowerdir=/host,upperdir=/ovl/u,workdir=/ovl/w ovl $R
mount -t proc proc $R/proc; mount -t sysfs sys $R/sys; mount -t devtmpfs dev $R/dev
mkdir -p $R/dev/pts $R/dev/shm; mount -t devpts devpts $R/dev/pts; mount -t tmpfs shm $R/dev/shm
mount -t tmpfs run $R/run; mount -t debugfs debugfs $R/sys/kernel/debug
mount --bind /out $R$OUTP
KV=$(uname -r); mkdir -p $R/usr/lib/modules; rm -rf $R/usr/lib/modules/$KV; ln -s $MODS $R/usr/lib/modules/$KV
# kernel module autoload (e.g. `ip link add ... type vcan`) must run modprobe inside the chroot
printf '#!/bin/sh\nexec /bin/chroot /newroot /sbin/modprobe "$@"\n' > /bin/modprobe-chroot
chmod +x /bin/modprobe-chroot; echo /bin/modprobe-chroot > /proc/sys/kernel/modprobe
chroot $R /sbin/modprobe configfs && mount -t configfs configfs $R/sys/kernel/config
echo VMTEST_START
chroot $R /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root TERM=dumb /bin/sh $OUTP/cmd
rc=$?; echo $rc > /out/exit-code; echo "VMTEST_EXIT=$rc"; sync; poweroff -f
EOF
}

prepare() {
  cd "$W"
  # Kernel: the one linux-image-amd64 currently points at, unless KVER pins it. When apt's lists
  # are gone (no network), fall back to a kernel already in the cache.
  local KV=${KVER:-}
  # apt-cache costs ~5 s: re-resolve only after apt's lists changed (apt-get update).
  if [ -z "$KV" ] && [ -s kver ] && [ -e "kroot/boot/vmlinuz-$(cat kver)" ] &&
     [ kver -nt /var/cache/apt/pkgcache.bin ] && [ kver -nt /var/lib/apt/lists ]; then
    KV=$(cat kver)
  fi
  if [ -z "$KV" ]; then
    KV=$(apt-cache depends linux-image-amd64 2>/dev/null | sed -n 's/.*Depends: linux-image-//p' | head -1)
    if [ -z "$KV" ] || ! apt-cache show "linux-image-$KV" >/dev/null 2>&1; then
      KV=$(ls kroot/boot 2>/dev/null | sed -n 's/^vmlinuz-//p' | head -1)
    fi
  fi
  [ -n "$KV" ] || skip "cannot resolve Debian's linux-image-amd64 (apt lists missing?) and no cached kernel"
  echo "$KV" > kver.tmp && mv kver.tmp kver

  if [ ! -e "kroot/boot/vmlinuz-$KV" ] || [ ! -e "src/gpio-sim.c" ]; then
    local VER
    VER=$(apt-cache show "linux-image-$KV" 2>/dev/null | awk '/^Version:/{print $2; exit}')
    [ -n "$VER" ] || skip "linux-image-$KV unknown to apt (apt-get update?)"
    rm -rf "debs/$KV"; mkdir -p "debs/$KV"
    # apt-get download as root warns that _apt cannot write here; harmless.
    (cd "debs/$KV" && apt-get download -q "linux-image-$KV" "linux-headers-$KV" \
        "linux-headers-${KV%-amd64}-common" "linux-kbuild-6.1=$VER" "linux-source-6.1=$VER" \
        >download.log 2>&1) || { cat "debs/$KV/download.log" >&2; skip "apt-get download of the kernel packages failed (no network?)"; }
    rm -rf kroot hdr src; mkdir -p src/x
    dpkg -x debs/$KV/linux-image-"$KV"_*.deb kroot
    for p in "linux-headers-$KV" "linux-headers-${KV%-amd64}-common" linux-kbuild-6.1; do
      dpkg -x debs/$KV/"$p"_*.deb hdr
    done
    sed -i "s#include /usr/src/#include $W/hdr/usr/src/#" "hdr/usr/src/linux-headers-$KV/Makefile"
    # Only three files of the 140 MB source tarball are needed: extract them, drop the rest.
    dpkg --fsys-tarfile debs/$KV/linux-source-6.1_*.deb | tar -xO ./usr/src/linux-source-6.1.tar.xz |
      tar -xJ -C src/x linux-source-6.1/drivers/gpio/gpio-sim.c linux-source-6.1/drivers/gpio/gpiolib.h \
        linux-source-6.1/kernel/irq/irq_sim.c
    cp src/x/linux-source-6.1/drivers/gpio/gpio-sim.c src/x/linux-source-6.1/drivers/gpio/gpiolib.h \
       src/x/linux-source-6.1/kernel/irq/irq_sim.c src/
    rm -rf src/x debs/$KV/linux-source-6.1_*.deb
  fi

  # gpio-sim.ko: CONFIG_GPIO_SIM and CONFIG_IRQ_SIM are unset in Debian 6.1 -> one module from
  # both sources. irq_to_desc() is not exported to modules; generic_handle_irq() reaches the same
  # handle_simple_irq through the descriptor.
  local M=kroot/lib/modules/$KV
  if [ ! -e "$M/extra/gpio-sim.ko" ]; then
    rm -rf gpiosim; mkdir gpiosim
    cp src/gpio-sim.c gpiosim/gpio-sim-main.c; cp src/gpiolib.h src/irq_sim.c gpiosim/
    sed -i 's/handle_simple_irq(irq_to_desc(irqnum));/generic_handle_irq(irqnum);/' gpiosim/irq_sim.c
    grep -q 'generic_handle_irq(irqnum)' gpiosim/irq_sim.c || die "irq_sim.c patch did not apply"
    printf 'obj-m := gpio-sim.o\ngpio-sim-y := gpio-sim-main.o irq_sim.o\n' > gpiosim/Kbuild
    make -s -C "hdr/usr/src/linux-headers-$KV" M="$W/gpiosim" modules >gpiosim/build.log 2>&1 ||
      { cat gpiosim/build.log >&2; die "gpio-sim module build failed"; }
    mkdir -p "$M/extra"; cp gpiosim/gpio-sim.ko "$M/extra/"
  fi
  # The kernel .deb ships no modules.dep.
  if [ ! -e "$M/modules.dep" ] || [ "$M/extra/gpio-sim.ko" -nt "$M/modules.dep" ]; then
    depmod -b kroot "$KV"
  fi

  # initramfs: static busybox + the modules needed to mount the 9p root and the overlay.
  local I=initramfs-$KV.cpio.gz
  write_init init.new
  if [ ! -e "$I" ] || ! cmp -s init.new init.used; then
    local D=$W/initramfs-src
    rm -rf "$D"; mkdir -p "$D"/{bin,mod,proc,sys,dev,host,newroot,ovl,out}
    cp /bin/busybox "$D/bin/"
    for a in sh mount insmod mkdir ln cat echo chroot poweroff sed sync chmod printf rm tr; do
      ln -s busybox "$D/bin/$a"
    done
    for m in virtio_pci 9pnet_virtio 9p overlay; do modprobe -d kroot -S "$KV" --show-depends $m; done |
      awk '$1=="insmod" && !s[$2]++ {print $2}' |
      while read -r f; do cp "$f" "$D/mod/"; basename "$f" >> "$D/mod/order"; done
    cp init.new "$D/init"
    chmod +x "$D/init"
    (cd "$D" && find . | cpio -o -H newc --quiet | gzip -1) > "$I.tmp" && mv "$I.tmp" "$I"
    mv init.new init.used
  fi
}

exec 9>"$W/.lock"
flock 9
t0=$(date +%s.%N)
prepare
flock -u 9
KV=$(cat "$W/kver")
echo "vmrig: kernel $KV ready in $W ($(elapsed "$t0") s prepare)" >&2
[ $PREPARE_ONLY = 0 ] || exit 0

# --- 2. run -----------------------------------------------------------------------------------
if [ -z "$OUT" ]; then OUT=$(mktemp -d "$W/runs/run.XXXXXX"); fi
mkdir -p "$OUT"; OUT=$(realpath "$OUT")
case "$OUT" in *" "*|*,*) die "--out path must not contain spaces or commas" ;; esac
{
  printf 'cd %q 2>/dev/null || cd /\n' "$HERE"
  # pass the caller's test configuration through the env -i in the guest's init
  for v in $(compgen -e | grep -E '^(STORETRACK_|VMTEST_)' || true); do printf 'export %s=%q\n' "$v" "${!v}"; done
  printf 'export VMRIG_OUT=%q\n' "$OUT"
  printf '%s\n' "$CMD"
} > "$OUT/cmd"
rm -f "$OUT/exit-code"
t1=$(date +%s.%N)
set +e
timeout "${VM_TIMEOUT:-900}" qemu-system-x86_64 -accel tcg,thread=multi -cpu max \
  -smp "${VM_SMP:-1}" -m "${VM_MEM:-1536}" -nographic -no-reboot -nic none \
  -kernel "$W/kroot/boot/vmlinuz-$KV" -initrd "$W/initramfs-$KV.cpio.gz" \
  -append "console=ttyS0 panic=-1 loglevel=4 vmrig.out=$OUT vmrig.mods=$W/kroot/lib/modules/$KV" \
  -fsdev local,id=r,path=/,security_model=none,readonly=on,multidevs=remap \
  -device virtio-9p-pci,fsdev=r,mount_tag=hostroot \
  -fsdev local,id=o,path="$OUT",security_model=none -device virtio-9p-pci,fsdev=o,mount_tag=out \
  </dev/null 2>&1 | tee "$OUT/console.log"
qrc=${PIPESTATUS[0]}
set -e
rc=$(cat "$OUT/exit-code" 2>/dev/null || echo 99)
[ "$qrc" = 124 ] && echo "vmrig: VM timed out after ${VM_TIMEOUT:-900} s" >&2
echo "vmrig: VM exit code $rc, $(elapsed "$t1") s in the VM, logs in $OUT" >&2
exit "$rc"
