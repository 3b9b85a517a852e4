#!/usr/bin/env bash
# Make sure a libLLVM that Mitsuba's integrators accept (>= 16; 19 is tested) is installed.
# Debian 12 ships libLLVM 15, on which Mitsuba dies with "LLVM ERROR: Cannot select ... fminimum".
set -euo pipefail
found=""
for v in 21 20 19 18 17 16; do
  for d in /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/lib /usr/lib64 "/usr/lib/llvm-$v/lib"; do
    if [ -e "$d/libLLVM-$v.so" ] || [ -e "$d/libLLVM.so.$v" ] || ls "$d"/libLLVM.so."$v".* >/dev/null 2>&1; then
      found="$v"; break 2
    fi
  done
done
if [ -n "${DRJIT_LIBLLVM_PATH:-}" ] && [ -e "$DRJIT_LIBLLVM_PATH" ]; then
  echo "ensure-llvm: using DRJIT_LIBLLVM_PATH=$DRJIT_LIBLLVM_PATH"; exit 0
fi
if [ -n "$found" ]; then echo "ensure-llvm: libLLVM $found found"; exit 0; fi
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  echo "ensure-llvm: installing libllvm19 with apt-get"
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
  exit 0
fi
echo "ensure-llvm: no libLLVM >= 16 found. Install one: 'sudo apt-get install libllvm19' (Debian/Ubuntu)," >&2
echo "  'brew install llvm' (macOS), or set DRJIT_LIBLLVM_PATH to a libLLVM shared library." >&2
exit 1
