#!/bin/sh
# Install Mitsuba 3 (and drjit, numpy, matplotlib, Pillow) into the user's
# Python for tools/mitsuba_moon.py and tools/frontier.py. Idempotent: pip
# skips what is already installed. Not part of CI.
#
# Mitsuba's llvm_* variants JIT-compile through libLLVM, found through
# DRJIT_LIBLLVM_PATH. drjit 1.5 emits llvm.maximum, which LLVM 15 (Debian
# 12's default) cannot select ("LLVM ERROR: Cannot select ... fmaximum",
# abort); Debian 12 has libllvm19 in bookworm/main, which works. Export the
# variable printed at the end before running the tools (they also set it
# themselves when it is unset).
set -eu
lib=/usr/lib/x86_64-linux-gnu/libLLVM-19.so
if [ ! -e "$lib" ]; then
    if [ "$(id -u)" = 0 ]; then apt-get install -y libllvm19; else sudo apt-get install -y libllvm19; fi
fi
python3 -m pip install --user --quiet mitsuba numpy matplotlib Pillow
DRJIT_LIBLLVM_PATH=$lib python3 -c "import mitsuba as mi; mi.set_variant('llvm_ad_mono'); print('mitsuba', mi.__version__, 'llvm_ad_mono OK')"
echo "export DRJIT_LIBLLVM_PATH=$lib"
