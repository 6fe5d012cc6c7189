#!/usr/bin/env bash
# HIL in a VM (docs/hil.md): slscand's libgpiod, V4L2 and libserialport backends against real
# kernel interfaces -- gpio-sim, vivid and a 16550 UART -- in qemu with Debian's 6.1 kernel.
# Behaviour, not latency: emulated time means nothing.
#
#   scripts/hil-vm.sh            # exit 0 when every guest check passed
# Environment: SLSCAN_HIL_CACHE (default build/hil-vm-cache: kernel packages, gpio-sim module,
# static build), SLSCAN_HIL_ABI (the kernel ABI, default 57 = what bookworm offers now).
set -euo pipefail
export PATH=$PATH:/usr/sbin:/sbin  # depmod

root=$(cd "$(dirname "$0")/.." && pwd)
abi=${SLSCAN_HIL_ABI:-57}
kver="6.1.0-${abi}-amd64"
cache=${SLSCAN_HIL_CACHE:-$root/build/hil-vm-cache}
# Beside build/dev, so that ccache (base_dir) sees the same relative paths and hits.
static_build=$root/build/hil-vm-static
work=$(mktemp -d /tmp/slscan-hil-vm.XXXXXX)
bridge_pid=
cleanup() {
  [ -n "$bridge_pid" ] && kill "$bridge_pid" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
say() { echo "hil-vm: $*"; }
start=$(date +%s)

for tool in qemu-system-x86_64 busybox cpio dpkg-deb make depmod file; do
  command -v "$tool" >/dev/null || { say "missing $tool (scripts/bootstrap.sh installs it)"; exit 2; }
done
[ -e /bin/busybox ] && file -L /bin/busybox | grep -q "statically linked" || { say "needs busybox-static"; exit 2; }
headers=/usr/src/linux-headers-$kver
[ -d "$headers" ] || { say "missing $headers: apt-get install linux-headers-$kver"; exit 2; }

# 1. Kernel image and modules, and the kernel source for gpio-sim (cached).
mkdir -p "$cache"
(cd "$cache" && for pkg in "linux-image-$kver" linux-source-6.1; do
  ls "$pkg"_*.deb >/dev/null 2>&1 || apt-get download "$pkg" >/dev/null 2>&1 || { echo "hil-vm: cannot download $pkg"; exit 2; }
done)
if [ ! -f "$cache/image/boot/vmlinuz-$kver" ]; then
  say "unpacking linux-image-$kver"
  rm -rf "$cache/image" && dpkg-deb -x "$cache"/linux-image-"$kver"_*.deb "$cache/image"
fi
# The package leaves modules.dep to depmod at install time.
[ -f "$cache/image/lib/modules/$kver/modules.dep" ] || depmod -b "$cache/image" "$kver"
modules=$cache/image/lib/modules/$kver

# 2. gpio-sim, out of tree: Debian does not build it. irq_to_desc is not exported in 6.1, so
# call generic_handle_irq instead (docs/hil.md).
gpio_sim=$cache/gpio-sim-$kver/gpio-sim.ko
if [ ! -f "$gpio_sim" ]; then
  say "building gpio-sim against $headers"
  src=$cache/src/linux-source-6.1
  if [ ! -f "$src/drivers/gpio/gpio-sim.c" ]; then
    mkdir -p "$cache/src"
    dpkg-deb --fsys-tarfile "$cache"/linux-source-6.1_*.deb | tar -xO ./usr/src/linux-source-6.1.tar.xz |
      tar -xJ -C "$cache/src" linux-source-6.1/drivers/gpio/gpio-sim.c linux-source-6.1/drivers/gpio/gpiolib.h \
        linux-source-6.1/kernel/irq/irq_sim.c
  fi
  m=$cache/gpio-sim-$kver
  rm -rf "$m" && mkdir -p "$m"
  cp "$src/drivers/gpio/gpio-sim.c" "$m/gpio-sim-main.c"
  cp "$src/drivers/gpio/gpiolib.h" "$m/"
  cp "$src/kernel/irq/irq_sim.c" "$m/"
  sed -i 's/handle_simple_irq(irq_to_desc(\([a-z_]*\)))/generic_handle_irq(\1)/' "$m/irq_sim.c"
  grep -q "generic_handle_irq" "$m/irq_sim.c" || { say "the irq_to_desc patch did not apply"; exit 1; }
  printf 'obj-m := gpio-sim.o\ngpio-sim-y := gpio-sim-main.o irq_sim.o\n' >"$m/Kbuild"
  make -s -C "$headers" M="$m" modules >"$m/build.log" 2>&1 || { cat "$m/build.log"; exit 1; }
fi

# 3. slscand's backends and the guest checker, statically linked (no libcamera, no host code).
if [ ! -f "$static_build/CMakeCache.txt" ]; then
  say "configuring the static build of the firmware backends"
  # The platform files set the library suffixes after the command line, so set them after
  # project(): every find_library (pkg-config's imported targets too) then takes the .a.
  echo 'set(CMAKE_FIND_LIBRARY_SUFFIXES .a)' >"$cache/static.cmake"
  cmake -S "$root" -B "$static_build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSLSCAN_WERROR=ON \
    -DSLSCAN_BUILD_HOST=OFF -DSLSCAN_BUILD_BENCH=OFF -DSLSCAND_LIBCAMERA=OFF -DSLSCAND_ARAVIS=OFF -DSLSCAN_AVAHI=OFF -DCMAKE_EXE_LINKER_FLAGS=-static \
    -DCMAKE_PROJECT_INCLUDE="$cache/static.cmake" >"$work/cmake.log" 2>&1 || { cat "$work/cmake.log"; exit 1; }
fi
# A no-op when nothing changed.
cmake --build "$static_build" -j2 --target slscan_hil_vm_check slscan_hil slscand >"$work/build.log" 2>&1 ||
  { tail -40 "$work/build.log"; exit 1; }
cmake --build "$root/build/dev" --target slscan_hil_uart_bridge >/dev/null 2>&1 ||
  cmake --build "$static_build" --target slscan_hil_uart_bridge >/dev/null
bridge=$root/build/dev/firmware/tools/hil/slscan_hil_uart_bridge
[ -x "$bridge" ] || bridge=$static_build/firmware/tools/hil/slscan_hil_uart_bridge

# 4. The initramfs: busybox, the modules vivid needs (in modules.dep order), gpio-sim, the checker.
init=$work/initramfs
mkdir -p "$init"/{bin,sbin,dev,proc,sys,tmp,modules,boards}
cp /bin/busybox "$init/bin/"
for applet in sh mount mkdir echo cat insmod sleep poweroff ls; do ln -s busybox "$init/bin/$applet"; done
cp "$static_build/firmware/tools/hil/slscan_hil_vm_check" "$static_build/firmware/tools/hil/slscan_hil" "$static_build/firmware/app/slscand" \
  "$init/bin/"
cp "$root/boards/qemu-vm.toml" "$init/boards/"
cp "$gpio_sim" "$init/modules/"
deps() {  # the module and what it needs, dependencies first
  local mod=$1 line dep
  line=$(grep -E "(^|/)$mod.ko:" "$modules/modules.dep") || return 0  # built in
  for dep in ${line#*:}; do deps "$(basename "$dep" .ko)"; done
  echo "${line%%:*}"
}
: >"$init/modules/order"
for mod in configfs vivid; do
  for path in $(deps "$mod" 2>/dev/null || true); do
    grep -qx "$(basename "$path")" "$init/modules/order" && continue
    cp "$modules/$path" "$init/modules/"
    basename "$path" >>"$init/modules/order"
  done
done
cat >"$init/init" <<'EOF'
#!/bin/sh
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev
for m in $(cat /modules/order); do insmod /modules/$m || echo "HIL-CHECK insmod.$m FAIL"; done
insmod /modules/gpio-sim.ko || echo "HIL-CHECK insmod.gpio-sim FAIL"
mount -t configfs none /sys/kernel/config 2>/dev/null
d=/sys/kernel/config/gpio-sim/slscan
mkdir -p $d/bank0 && echo 8 > $d/bank0/num_lines && echo slscan-vm > $d/bank0/label && echo 1 > $d/live
chip=$(ls -d /sys/devices/platform/gpio-sim.*/gpiochip* 2>/dev/null | head -n 1)
[ -n "$chip" ] && echo "HIL-CHECK gpio-sim ok $chip" || echo "HIL-CHECK gpio-sim FAIL no chip"
[ -e /dev/video0 ] && echo "HIL-CHECK vivid ok /dev/video0" || echo "HIL-CHECK vivid FAIL no /dev/video0"
echo "HIL-CHECK slscand ok $(slscand --list-backends)"
# slscand itself, launched by the harness as on a bench: it opens every device through the board
# file (gpio-sim by label, its projector lines requested), then vivid, which has no manual
# exposure control: slscand must refuse to start, naming the device and the missing control,
# the harness must report that it could not run the scan (exit 3), and no line may stay high.
slscan_hil --board /boards/qemu-vm.toml --slscand /bin/slscand --views 1 --no-timing --no-realtime \
  --out /tmp/hil >/tmp/hil.out 2>&1
rc=$?
sed 's/^/guest: /' /tmp/hil.out
grep -q "cannot open the board's devices: /dev/video0: the camera has no manual exposure control" /tmp/hil.out &&
  grep -q "slscand exited before listening (exit code 1)" /tmp/hil.out && [ $rc -eq 3 ] &&
  echo "HIL-CHECK slscand.vivid refused ok" || echo "HIL-CHECK slscand.vivid refused FAIL exit $rc"
v=""; for l in 0 1 3 4; do v="$v$(cat $chip/sim_gpio$l/value)"; done
[ "$v" = "0000" ] && echo "HIL-CHECK slscand.lines low ok" || echo "HIL-CHECK slscand.lines low FAIL $v"
slscan_hil_vm_check --board /boards/qemu-vm.toml --sysfs-chip "$chip"
poweroff -f
EOF
chmod +x "$init/init"
(cd "$init" && find . | cpio -o -H newc --quiet | gzip -1) >"$work/initramfs.gz"

# 5. Boot: console on ttyS0 (stdio), ttyS1 on the bridge's socket. Give both -serial options.
sock=$work/ttyS1.sock
"$bridge" "$sock" >"$work/bridge.log" 2>&1 &
bridge_pid=$!
for _ in $(seq 50); do grep -q "BRIDGE listening" "$work/bridge.log" 2>/dev/null && break; sleep 0.1; done
say "booting linux $kver (tcg)"
boot=$(date +%s)
timeout 300 qemu-system-x86_64 -accel tcg -m 512 -smp 1 -nographic -no-reboot \
  -kernel "$cache/image/boot/vmlinuz-$kver" -initrd "$work/initramfs.gz" \
  -append "console=ttyS0 quiet panic=-1" \
  -serial stdio -serial "unix:$sock" -monitor none >"$work/console.log" 2>&1 || true
wait "$bridge_pid" 2>/dev/null || true
bridge_pid=

grep -E "^(HIL-|guest: )" "$work/console.log" | tr -d '\r' || true
grep -E "^UART> " "$work/bridge.log" | sed 's/^/host: /' | head -12
grep -E "^BRIDGE lines" "$work/bridge.log" | sed 's/^/host: /' 
failed=0
grep -q "^HIL-DONE 0" "$work/console.log" || { say "guest checks failed or did not finish"; failed=1; }
grep -q "HIL-CHECK.* FAIL" "$work/console.log" && failed=1
# The host saw the guest's turntable commands: an absolute move to 120 deg, and no more
# lines after the silent switch.
grep -q "^UART> .*X120" "$work/bridge.log" || { say "the emulator never saw the move to 120 deg"; failed=1; }
grep -q "^BRIDGE .*angle=120.000 silent=1" "$work/bridge.log" ||
  { say "emulator did not end at 120 deg with the silent switch: $(grep '^BRIDGE lines' "$work/bridge.log")"; failed=1; }
if [ $failed -ne 0 ]; then
  say "console log:"; tail -40 "$work/console.log"
fi
say "$([ $failed -eq 0 ] && echo PASS || echo FAIL) (VM $(($(date +%s) - boot)) s, total $(($(date +%s) - start)) s)"
exit $failed
