"""Locate a libLLVM that Dr.Jit's LLVM backend can use (LLVM >= 19).

LLVM 14 is refused by Dr.Jit, and LLVM 15/16 abort the whole process on the
first render (``LLVM ERROR: Cannot select: ... fminimum``). This module must run
*before* Dr.Jit is imported so that ``DRJIT_LIBLLVM_PATH`` can point it to a
working library; :func:`check_loaded` verifies the library Dr.Jit actually loaded.
"""
import glob
import os
import re

MIN_LLVM_MAJOR = 19
_SEARCH_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64",
                "/usr/lib", "/usr/local/lib", "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib")

INSTALL_HINT = (
    "Install LLVM >= {m} (Debian/Ubuntu: `apt-get install libllvm19`, or run `make setup`), "
    "or point DRJIT_LIBLLVM_PATH to a libLLVM.so of version >= {m}."
).format(m=MIN_LLVM_MAJOR)


class LLVMNotFoundError(ImportError):
    """Raised when no libLLVM >= 19 is available for Dr.Jit's LLVM backend."""


def _major(path):
    m = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
    return int(m.group(1)) if m else None


def find_libllvm():
    """Return the path of the newest libLLVM >= 19 on this machine, or None."""
    candidates = []
    for d in _SEARCH_DIRS:
        for p in glob.glob(os.path.join(d, "libLLVM*.so*")) + glob.glob(os.path.join(d, "libLLVM*.dylib")):
            major = _major(p)
            if major is not None and major >= MIN_LLVM_MAJOR:
                candidates.append((major, p))
    return max(candidates)[1] if candidates else None


def configure():
    """Set DRJIT_LIBLLVM_PATH to a suitable libLLVM if the user did not choose one."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        return os.environ["DRJIT_LIBLLVM_PATH"]
    path = find_libllvm()
    if path is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def check_loaded():
    """Raise LLVMNotFoundError unless Dr.Jit runs on LLVM >= 19."""
    import drjit as dr
    try:
        version = dr.detail.llvm_version()
    except Exception:  # backend inactive: no usable library found at all
        version = None
    if not version or version[0] < MIN_LLVM_MAJOR:
        found = "no usable libLLVM" if not version else "LLVM %d.%d.%d" % tuple(version)
        raise LLVMNotFoundError(
            "mi_plugins: Dr.Jit's LLVM backend found %s, but needs LLVM >= %d "
            "(older versions abort the process during rendering). %s"
            % (found, MIN_LLVM_MAJOR, INSTALL_HINT))
    return version
