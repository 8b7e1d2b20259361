"""The ``.npz`` files that hold a predictor's state: written atomically, read with clear errors."""

from __future__ import annotations

import io
import json
import os
import zipfile

import numpy as np

__all__ = ["write_archive", "read_archive"]


def write_archive(path: str | os.PathLike, meta: dict, arrays: dict[str, np.ndarray]) -> None:
    """Write JSON ``meta`` and named ``arrays`` to ``path``; a crash never leaves half a file."""
    buffer = io.BytesIO()
    np.savez(buffer, meta=np.array(json.dumps(meta)), **arrays)
    tmp = f"{os.fspath(path)}.tmp"
    with open(tmp, "wb") as handle:
        handle.write(buffer.getvalue())
    os.replace(tmp, path)


def read_archive(path: str | os.PathLike, *, magic: str, version: int, what: str,
                 written_by: str) -> tuple[dict, dict[str, np.ndarray]]:
    """Read a file written by :func:`write_archive`, checking its magic string and version.

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming ``what`` was
    expected for a corrupt, foreign or other-version file.
    """
    try:
        with np.load(path, allow_pickle=False) as archive:
            meta = json.loads(str(archive["meta"]))
            arrays = {name: archive[name] for name in archive.files if name != "meta"}
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, OSError, KeyError, ValueError, EOFError) as error:
        raise ValueError(f"{path}: not a {what} (expected a .npz written by {written_by}): {error}") from error
    if not isinstance(meta, dict) or meta.get("magic") != magic:
        found = meta.get("magic") if isinstance(meta, dict) else None
        raise ValueError(f"{path}: not a {what} (magic {found!r})")
    if meta.get("format_version") != version:
        raise ValueError(f"{path}: expected format version {version}, got {meta.get('format_version')!r}")
    return meta, arrays
