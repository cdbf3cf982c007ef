#!/usr/bin/env bash
# Bootstrap what `make` targets need: Debian packages (installed when missing and
# running as root, otherwise the exact command is printed) and a local virtualenv.
# Usage: tools/bootstrap.sh [apt-group ...]   groups: test lint firmware qemu fuzz bench fleet dds
set -euo pipefail
cd "$(dirname "$0")/.."

declare -A GROUP_PKGS=(
  [test]="gcc-arm-none-eabi libnewlib-arm-none-eabi libcmocka-dev qemu-system-arm valgrind chromium mosquitto openssl cppcheck systemd"
  [lint]="cppcheck"
  [firmware]="gcc-arm-none-eabi libnewlib-arm-none-eabi"
  [qemu]="gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm"
  [fuzz]="clang libclang-rt-14-dev libcmocka-dev"
  [bench]="gcc-arm-none-eabi libnewlib-arm-none-eabi valgrind"
  [demo]=""
  [fleet]="mosquitto"
  # ROS 2's default middleware for the DDS interoperability tests (tests/io/test_ros2.py): Fast DDS,
  # its IDL code generator (Java: Debian pulls a headless JRE) and a C++ compiler for the peer.
  [dds]="libfastrtps-dev fastddsgen g++"
)

missing=()
for g in "$@"; do
  for p in ${GROUP_PKGS[$g]:-}; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
done
# A Python without the venv module (Debian's python3 without python3-venv).
if ! python3 -c 'import ensurepip, venv' >/dev/null 2>&1; then missing+=(python3-venv); fi

if [ ${#missing[@]} -gt 0 ]; then
  # shellcheck disable=SC2207
  missing=($(printf '%s\n' "${missing[@]}" | sort -u))
  if [ "$(id -u)" = 0 ]; then
    echo "bootstrap: installing Debian packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    echo "bootstrap: missing Debian packages. Install them with:" >&2
    echo "  sudo apt-get install -y ${missing[*]}" >&2
    exit 1
  fi
fi

VENV=${VENV:-.venv}
stamp="$VENV/.pfdoa-installed"
if [ ! -x "$VENV/bin/python" ]; then
  echo "bootstrap: creating virtualenv $VENV"
  python3 -m venv "$VENV"
fi
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "bootstrap: installing Python packages into $VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
  "$VENV/bin/python" -m pip install -q -e '.[test,ros,ros2,lint]'
  touch "$stamp"
fi
