#!/bin/sh
# System packages slamfront needs but its wheels do not bundle.
#   sh scripts/sysdeps.sh        what running needs: Open3D links libusb-1.0 (for RealSense
#                                support) even when no camera is used
#   sh scripts/sysdeps.sh test   also what the tests need: Debian's chromium, which opens
#                                report.html headless (tests/test_report_html.py)
#   sh scripts/sysdeps.sh bench  also what the benchmarks need: qemu-user, whose emulated
#                                older CPUs bench_machine_spread.py renders frames on
# As root with apt-get the missing packages are installed; otherwise the command to
# install them is printed (and, for what running needs, make stops).
set -e
missing=""
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    missing="$missing libusb-1.0-0"
fi
optional=""
if [ "$1" = "test" ] && ! command -v chromium >/dev/null 2>&1; then
    optional="$optional chromium"
fi
if [ "$1" = "bench" ] && ! command -v qemu-x86_64 >/dev/null 2>&1; then
    optional="$optional qemu-user"
fi
[ -z "$missing$optional" ] && exit 0
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing system packages:$missing$optional"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing $optional >/dev/null 2>&1 || {
        apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing $optional >/dev/null
    }
    exit 0
fi
if [ -n "$optional" ]; then
    if [ "$1" = "test" ]; then
        echo "the tests need these system packages:$optional (the report test fails without them)" >&2
    else
        echo "the benchmarks need these system packages:$optional (without them the emulated-CPU rows are not run)" >&2
    fi
    echo "install them, e.g.: sudo apt-get install$optional" >&2
fi
if [ -n "$missing" ]; then
    echo "slamfront needs these system packages:$missing" >&2
    echo "install them, e.g.: sudo apt-get install$missing" >&2
    exit 1
fi
