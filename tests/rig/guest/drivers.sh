# Rig self-test with Debian's own tools: CAN FD over vcan, gpio-sim edges seen by libgpiod,
# vivid output->capture loopback byte-identical. If this fails, the other results mean nothing.
. "$(dirname "$0")/lib.sh"
echo "-- CAN FD over vcan (mtu 72)"
vcan_up vcan0
candump -n 2 -T 5000 vcan0 > $T/dump & P=$!
waitfor 'grep -q vcan0 /proc/net/can/rcvlist_all' || fail "candump did not bind"
cansend vcan0 123#DEADBEEF; cansend vcan0 456##1.00112233445566778899AABBCCDDEEFF
wait $P; cat $T/dump
grep -q '456  \[16\]  00 11 22' $T/dump || fail "64-byte-capable FD frame not seen by candump"
echo "-- gpio-sim + libgpiod"
gpiosim_new drv 4
timeout 20 gpiomon -b -n 2 -F '%e' "$GS_CHIP" 0 > $T/mon & P=$!
waitfor "gpioinfo $GS_CHIP | grep -q gpiomon" || fail "gpiomon did not request the line"
echo pull-up > $GS_SYS/sim_gpio0/pull; waitfor "grep -q '^1' $T/mon" || fail "no rising edge"
echo pull-down > $GS_SYS/sim_gpio0/pull
wait $P; [ "$(echo $(cat $T/mon))" = "1 0" ] || fail "gpiomon saw '$(cat $T/mon)', want '1 0'"
echo "-- vivid output -> capture loopback"
modprobe vivid n_devs=1 node_types=0x101 || fail "modprobe vivid"
v4l2-ctl -d /dev/video0 -i 2 -s pal -c loop_video=1,osd_text_mode=2 >/dev/null || fail "vivid capture setup"
v4l2-ctl -d /dev/video1 -o 0 -s pal >/dev/null || fail "vivid output setup"
head -c 829440 /dev/urandom > $T/in.yuv
v4l2-ctl -d /dev/video1 --stream-out-mmap 3 --stream-from $T/in.yuv --stream-loop 2>/dev/null & P=$!
sleep 1
timeout 20 v4l2-ctl -d /dev/video0 --stream-mmap 3 --stream-skip 3 --stream-count 1 --stream-to $T/out.yuv 2>/dev/null
kill $P; wait $P
cmp $T/in.yuv $T/out.yuv || fail "vivid loopback frame differs"
echo "drivers OK"
