#!/usr/bin/env bash
# Make sure a libLLVM >= 19 exists for Dr.Jit's LLVM backend (LLVM 14-16 abort
# the process during rendering). Installs Debian's libllvm19 when possible.
set -euo pipefail
found=""
for f in /usr/lib/x86_64-linux-gnu/libLLVM*.so* /usr/lib/aarch64-linux-gnu/libLLVM*.so* /usr/lib/libLLVM*.so* /usr/local/lib/libLLVM*.so*; do
    [ -e "$f" ] || continue
    major=$(basename "$f" | sed -nE 's/^libLLVM(-|\.so\.)([0-9]+).*/\2/p')
    if [ -n "$major" ] && [ "$major" -ge 19 ]; then found="$f"; fi
done
if [ -n "${DRJIT_LIBLLVM_PATH:-}" ]; then
    echo "using DRJIT_LIBLLVM_PATH=$DRJIT_LIBLLVM_PATH"; exit 0
fi
if [ -n "$found" ]; then
    echo "found LLVM >= 19: $found"; exit 0
fi
echo "No libLLVM >= 19 found (Dr.Jit's LLVM backend aborts with LLVM 14-16); installing Debian's libllvm19 ..."
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
        echo "ERROR: need root to run 'apt-get install libllvm19'. Install LLVM >= 19 yourself and/or set DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so.19" >&2
        exit 1
    fi
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "ERROR: apt-get is not available. Install LLVM >= 19 (e.g. 'brew install llvm', 'dnf install llvm-libs') and set DRJIT_LIBLLVM_PATH to its libLLVM." >&2
    exit 1
fi
$SUDO apt-get update -qq
if ! $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null; then
    echo "ERROR: 'apt-get install libllvm19' failed. Install LLVM >= 19 and set DRJIT_LIBLLVM_PATH to its libLLVM.so." >&2
    exit 1
fi
echo "installed libllvm19"
