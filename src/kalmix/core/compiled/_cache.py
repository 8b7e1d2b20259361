"""Numba cache location keyed on the compiled sources (see the package docstring)."""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

_CORE = Path(__file__).resolve().parent.parent
#: numba options of every compiled-engine function.
JIT = dict(cache=True, nogil=True, error_model="numpy", boundscheck=False)
#: The drivers over targets (``_run_block``): no reference counting. They allocate nothing (their scratch
#: comes from the caller), and without it the array views of their inner loops cost nothing: the kinematic
#: family's driver ran 2.5x faster on one thread (10,000 targets x 50 rows).
KERNEL_JIT = dict(JIT, _nrt=False)
#: Every file whose code ends up in a compiled kernel.
KERNEL_SOURCES = (
    "_numba_linalg.py", "_numba_kernels.py", "_numba_scalar.py",
    "compiled/kinematic.py", "compiled/ar.py", "compiled/turn.py", "compiled/rules.py", "compiled/screen.py", "compiled/_cache.py",
    "compiled/calibration.py", "compiled/lead.py", "compiled/akf.py",
)
#: The other kalmix files the kernel sources import from: numba freezes a global (``screen.ZERO``,
#: ``families/kinematic.RESTART_NIS``) into the compiled code, so they key the cache too (a test checks the list).
CONSTANT_SOURCES = ("screen.py", "families/kinematic.py", "calibration.py")
#: What the cache directory is keyed on (with numba's version).
COMPILED_SOURCES = KERNEL_SOURCES + CONSTANT_SOURCES


@functools.cache
def numba_available() -> bool:
    """True when numba can be imported (the ``fast`` extra is installed)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def source_hash() -> str:
    digest = hashlib.sha256()
    for name in COMPILED_SOURCES:
        digest.update(name.encode())
        digest.update((_CORE / name).read_bytes())
    import numba

    digest.update(numba.__version__.encode())
    return digest.hexdigest()[:16]


def cache_directory() -> Path:
    root = os.environ.get("KALMIX_CACHE_DIR")
    if root:
        base = Path(root)
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "kalmix"
    return base / f"numba-{source_hash()}"


@functools.cache
def configure_cache() -> Path:
    """Point numba's cache at :func:`cache_directory` (once, before any kalmix kernel is compiled)."""
    import numba

    path = cache_directory()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        # a read-only home, or KALMIX_CACHE_DIR naming a file: a keyed directory in the temporary directory instead
        # (numba's own default, the sources' __pycache__, is not keyed on the constants the kernels import)
        import tempfile
        import warnings

        fallback = Path(tempfile.gettempdir()) / f"kalmix-{getattr(os, 'getuid', lambda: 0)()}" / path.name
        warnings.warn(f"cannot use the compiled-kernel cache {str(path)!r} ({error.strerror or error}); "
                      f"using {str(fallback)!r}", RuntimeWarning, stacklevel=2)
        try:
            fallback.mkdir(parents=True, exist_ok=True)
        except OSError:
            return path   # nowhere writable: numba's default
        path = fallback
    numba.config.CACHE_DIR = str(path)
    return path
