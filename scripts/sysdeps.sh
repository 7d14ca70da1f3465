#!/bin/sh
# System libraries slamfront's wheels need but do not bundle.
# Open3D links libusb-1.0 (for RealSense support) even when no camera is used.
set -e
missing=""
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    missing="$missing libusb-1.0-0"
fi
[ -z "$missing" ] && exit 0
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing system packages:$missing"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null 2>&1 || {
        apt-get update -qq >/dev/null 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
    }
else
    echo "slamfront needs these system packages:$missing" >&2
    echo "install them, e.g.: sudo apt-get install$missing" >&2
    exit 1
fi
