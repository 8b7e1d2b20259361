"""Numba cache location keyed on the compiled sources (see the package docstring)."""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

_CORE = Path(__file__).resolve().parent.parent
_PACKAGE = _CORE.parent
#: numba options of every compiled-engine function.
JIT = dict(cache=True, nogil=True, error_model="numpy", boundscheck=False)
#: The drivers over targets (each family's ``kernel``): no reference counting. They allocate nothing (their scratch
#: comes from the caller), and without it the array views of their inner loops cost nothing: the kinematic
#: family's driver ran 2.5x faster on one thread (10,000 targets x 50 rows).
KERNEL_JIT = dict(JIT, _nrt=False)
#: Every file whose code ends up in a compiled kernel.
KERNEL_SOURCES = (
    "_numba_linalg.py", "_numba_kernels.py", "_numba_akf_gate.py", "_numba_akf_rls.py", "_numba_akf_filter.py",
    "_numba_akf_target.py",
    "compiled/kinematic.py", "compiled/ar.py", "compiled/turn.py", "compiled/ct.py", "compiled/rules.py",
    "compiled/boa.py", "compiled/rule_rows.py",
    "compiled/screen.py",
    "compiled/_cache.py", "compiled/calibration.py", "compiled/lead.py", "compiled/akf.py", "compiled/reach.py",
    "compiled/masks.py", "compiled/stage.py",
)
#: The GPU engine's modules: their CPU-side numba functions are cached too. What they import from the spec
#: modules (state classes) is used on the host only, so the import check leaves them out.
GPU_SOURCES = ("compiled/gpu.py", "compiled/gpu_staged.py")
#: The other kalmix files the kernel sources import from: numba freezes a global (``screen.ZERO``,
#: ``families/kinematic.RESTART_NIS``) into the compiled code, so they key the cache too (a test checks the list).
CONSTANT_SOURCES = ("screen.py", "families/kinematic.py", "families/ct.py", "calibration.py", "aggregators/boa.py")
#: What the cache directory is keyed on (with numba's version).
COMPILED_SOURCES = KERNEL_SOURCES + GPU_SOURCES + CONSTANT_SOURCES


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
        import warnings

        fallback = _private_fallback(path.name)
        if fallback is None:
            warnings.warn(f"cannot use the compiled-kernel cache {str(path)!r} ({error.strerror or error}), nor a "
                          "private temporary directory: numba's default cache is used", RuntimeWarning, stacklevel=2)
            return path
        warnings.warn(f"cannot use the compiled-kernel cache {str(path)!r} ({error.strerror or error}); using "
                      f"{str(fallback)!r}", RuntimeWarning, stacklevel=2)
        path = fallback
    numba.config.CACHE_DIR = str(path)
    _locate_by_package_path()
    return path


@functools.cache
def _locate_by_package_path() -> None:
    """Cache kalmix's kernels by their file's place in the package, not by its absolute path (once per process).

    numba names a function's cache subdirectory (under ``numba.config.CACHE_DIR``) after a hash of its file's
    absolute directory, so the same sources in another place (an installed copy and its checkout, a second
    virtual environment or clone) compiled everything again into a directory of their own. The directory
    :func:`configure_cache` sets is keyed on the content of every compiled source already, and this locator
    stamps a file by its content too (numba before 0.61 stamps it by its modification time), so every copy of
    the same sources shares one cache. Functions of other files are left to numba's own locators, and so is
    everything where ``NUMBA_CACHE_LOCATOR_CLASSES`` sets numba's list."""
    import hashlib

    import numba
    from numba.core import caching

    base = getattr(caching, "_CacheLocator", None)
    impl = getattr(caching, "CacheImpl", None)
    if base is None or not isinstance(getattr(impl, "_locator_classes", None), list):   # other numba internals
        return

    class PackageLocator(base):
        def __init__(self, py_func, source: Path, root: str):
            self._source = source
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(root, source.parent.relative_to(_PACKAGE).as_posix().replace("/", "_"))

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            return hashlib.sha256(self._source.read_bytes()).hexdigest()

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            root = numba.config.CACHE_DIR
            try:
                source = Path(py_file).resolve()
                source.relative_to(_PACKAGE)
            except (ValueError, OSError):
                return None   # not a kalmix file
            if not root:
                return None
            self = cls(py_func, source, root)
            try:
                self.ensure_cache_path()
            except OSError:
                return None
            return self

    impl._locator_classes.insert(0, PackageLocator)


def _private_fallback(name: str) -> Path | None:
    """``<tmp>/kalmix-<uid>/<name>``, if that parent is a directory of this user's that no one else can write
    (numba's cache index is pickled: a directory another user made in advance could hand us code); else a new
    private directory for this process; None if neither can be made."""
    import stat
    import tempfile

    uid = os.getuid() if hasattr(os, "getuid") else None
    base = Path(tempfile.gettempdir()) / f"kalmix-{uid if uid is not None else 'user'}"
    try:
        base.mkdir(mode=0o700, exist_ok=True)
        info = base.lstat()
        private = stat.S_ISDIR(info.st_mode) and not info.st_mode & 0o022 and (uid is None or info.st_uid == uid)
        if private:
            (base / name).mkdir(mode=0o700, exist_ok=True)
            return base / name
    except OSError:
        pass
    try:
        return Path(tempfile.mkdtemp(prefix="kalmix-numba-"))
    except OSError:
        return None
