"""The ``.npz`` files that hold a predictor's state: written durably, read lazily with clear errors.

Writing: the archive goes to a uniquely named temporary file in the destination's
directory, is fsynced, renamed over the destination (atomic on POSIX) and the directory
is fsynced, so a crash or a concurrent writer never leaves half a file, and two writers
never share a temporary name.

Reading: only the members a caller asks for are decompressed, each after checking the
size its zip entry declares against the size the caller expects (a state file with a
huge unused or oversized member is refused, not inflated).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import stat
import tempfile
import zipfile

import numpy as np

__all__ = ["write_archive", "replaced_file", "save_figure", "open_archive", "Archive"]

#: Room for the ``.npy`` header in front of a member's data (the format caps it at 64 KiB).
_NPY_HEADER_ROOM = 65_536 + 16


def _new_file_mode(path: str) -> int:
    """Permissions for the new file: those of the file it replaces, else 0o666 minus the umask."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def _fsync_directory(directory: str) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory handles
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - file systems that refuse fsync on a directory
        pass
    finally:
        os.close(fd)


def _json_default(value):
    """numpy numbers and arrays in the settings (``seed=np.int64(1)``, ``forgetting_levels=np.array(...)``) as the
    Python values they stand for; anything else is refused by name."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"a setting of type {type(value).__name__} cannot be saved in a state file: {value!r:.80}")


def write_archive(path: str | os.PathLike, meta: dict, arrays: dict[str, np.ndarray]) -> None:
    """Write JSON ``meta`` and named ``arrays`` to ``path``; a crash never leaves half a file.

    A symbolic link is followed (its target is replaced, the link stays); a path that exists
    and is not a regular file (a device, a FIFO, a directory) is refused with a ``ValueError``.
    An ``OSError`` names ``path``, not the temporary file.
    """
    with replaced_file(path, what="a state file path") as handle:
        np.savez(handle, meta=np.array(json.dumps(meta, default=_json_default)), **arrays)


@contextlib.contextmanager
def replaced_file(path: str | os.PathLike, mode: str = "wb", *, what: str = "a file path", output: bool = False):
    """A handle to write ``path`` whole or not at all: a uniquely named temporary file beside it, fsynced and
    renamed over it when the block ends without an exception (the directory fsynced too), removed otherwise.
    A Ctrl-C, a full disk or a crash leaves the previous file, never half of a new one.

    A symbolic link is followed (its target is replaced, the link stays); a path that exists and is not a
    regular file is refused with a ``ValueError`` (``what`` names what was expected); an ``OSError`` names
    ``path``, not the temporary file. The new file keeps the permissions of the one it replaces.

    ``output`` (a command's ``--json``, a figure): as ``open(path, mode)`` would where no replace can be
    done: a path under ``/dev`` or ``/proc`` (``/dev/stdout``, a pipe or a redirected file behind it) and
    a character device or a FIFO are written directly, and so is a writable file in a directory that
    is not; a file that is not writable is refused (``PermissionError``), not replaced.
    """
    given = os.fspath(path)
    path = os.path.realpath(given)
    try:
        kind = os.stat(given).st_mode   # through links, as open() goes (a pipe's /proc link has no real path)
    except OSError:
        kind = None
    text = {} if "b" in mode else {"encoding": "utf-8"}
    if output and kind is not None:
        special = os.path.abspath(given).startswith(("/dev/", "/proc/"))
        if not stat.S_ISDIR(kind) and not os.access(given, os.W_OK):
            raise PermissionError(errno.EACCES, f"cannot write {given!r}: permission denied (the file is read-only)")
        if special or stat.S_ISCHR(kind) or stat.S_ISFIFO(kind) or (
                stat.S_ISREG(kind) and not os.access(os.path.dirname(path), os.W_OK)):
            with open(given, mode, **text) as handle:
                yield handle
            return
    if kind is not None and not stat.S_ISREG(kind):
        described = "a directory" if stat.S_ISDIR(kind) else "not a regular file (a device, a FIFO or a socket)"
        raise ValueError(f"{given}: expected {what}, and it is {described}; give a file name")
    directory = os.path.dirname(path)
    new_mode = _new_file_mode(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(path)}.", suffix=".tmp")
    except OSError as error:
        raise OSError(error.errno, f"cannot write {given!r}: {error.strerror}") from None
    try:
        with os.fdopen(fd, mode, **text) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, new_mode)
        os.replace(tmp, path)
    except BaseException as error:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(error, OSError):
            raise OSError(error.errno, f"cannot write {given!r}: {error.strerror}") from None
        raise
    _fsync_directory(directory)


def save_figure(fig, path: str | os.PathLike, **options) -> str:
    """``fig.savefig`` through :func:`replaced_file`, in the format its extension names (PNG without one)."""
    extension = os.path.splitext(os.fspath(path))[1].lstrip(".").lower() or "png"
    with replaced_file(path, what="a figure file path", output=True) as handle:
        fig.savefig(handle, format=extension, **options)
    return os.fspath(path)


class Archive:
    """An open archive: its checked ``meta`` and members read on demand (see :func:`open_archive`)."""

    def __init__(self, zip_file: zipfile.ZipFile, path, meta: dict, what: str):
        self._zip, self.path, self.meta, self._what = zip_file, path, meta, what

    @property
    def names(self) -> list[str]:
        """Array member names (without ``.npy``), ``meta`` excluded."""
        return [n[:-4] for n in self._zip.namelist() if n.endswith(".npy") and n != "meta.npy"]

    def size(self, name: str) -> int:
        """Uncompressed size that member ``name`` declares (0 if absent), read without decompressing."""
        try:
            return self._zip.getinfo(f"{name}.npy").file_size
        except KeyError:
            return 0

    def array(self, name: str, shape: tuple, dtype, label: str | None = None) -> np.ndarray:
        """Member ``name``, which must hold ``shape`` and ``dtype``; ``ValueError`` otherwise.

        The size declared by the zip entry is checked before anything is decompressed;
        messages call the member ``label`` (default ``name``).
        """
        dtype = np.dtype(dtype)
        what = name if label is None else label
        try:
            info = self._zip.getinfo(f"{name}.npy")
        except KeyError:
            raise ValueError(f"{self.path}: field {what!r} missing (the {self._what} is corrupt or of "
                             "another version)") from None
        expected = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if info.file_size > expected + _NPY_HEADER_ROOM:
            raise ValueError(f"{self.path}: field {what!r} expected {expected} bytes for shape {tuple(shape)} "
                             f"{dtype}, the archive declares {info.file_size}")
        try:
            with self._zip.open(info) as handle:
                value = np.lib.format.read_array(handle, allow_pickle=False)
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
            raise ValueError(f"{self.path}: field {what!r} is unreadable: {error}") from error
        if value.shape != tuple(shape) or value.dtype != dtype:
            raise ValueError(f"{self.path}: field {what!r} expected shape {tuple(shape)} {dtype}, "
                             f"got {value.shape} {value.dtype}")
        return value


@contextlib.contextmanager
def open_archive(path: str | os.PathLike, *, magic: str, version: int | tuple[int, ...], what: str, written_by: str,
                 max_meta_bytes: int = 1 << 30):
    """Open a file written by :func:`write_archive`, checking its magic string and version.

    Yields an :class:`Archive`. Raises ``TypeError`` for a ``path`` that is not a path, ``FileNotFoundError``
    for a missing file and ``ValueError`` naming ``what`` was expected for a directory, a corrupt, foreign
    (``.npy``, pickle, other zip) or other-version file.
    """
    if not isinstance(path, (str, bytes, os.PathLike)):   # (os.path.isdir takes an int for a file descriptor)
        raise TypeError(f"path: expected the path of a {what} (str or os.PathLike), got {type(path).__name__} "
                        f"{path!r:.80}")
    if os.path.isdir(path):
        raise ValueError(f"{path}: expected a {what}, got a directory")
    bad = f"{path}: not a {what} (expected a .npz written by {written_by})"
    try:
        zip_file = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as error:
        raise ValueError(f"{bad}: {error}") from error
    with zip_file:
        try:
            info = zip_file.getinfo("meta.npy")
        except KeyError:
            raise ValueError(f"{bad}: it has no 'meta' entry") from None
        if info.file_size > max_meta_bytes:
            raise ValueError(f"{bad}: its 'meta' entry declares {info.file_size} bytes")
        try:
            with zip_file.open(info) as handle:
                meta = json.loads(str(np.lib.format.read_array(handle, allow_pickle=False)))
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
            raise ValueError(f"{bad}: {error}") from error
        if not isinstance(meta, dict) or meta.get("magic") != magic:
            found = meta.get("magic") if isinstance(meta, dict) else None
            raise ValueError(f"{path}: not a {what} (magic {found!r})")
        versions = (version,) if isinstance(version, int) else tuple(version)
        if meta.get("format_version") not in versions:
            expected = " or ".join(map(str, versions))
            raise ValueError(f"{path}: expected format version {expected}, got {meta.get('format_version')!r} "
                             f"(a {what} of another kalmix version)")
        yield Archive(zip_file, path, meta, what)

