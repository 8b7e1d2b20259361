"""Helpers shared by the sub-commands: JSON output and progress bars."""

from __future__ import annotations

import contextlib
import json

import numpy as np


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def write_json(path: str, data) -> None:
    """Write ``data`` (numpy scalars and arrays allowed) as indented JSON."""
    with open(path, "w", encoding="utf-8") as handle:
        json.dump(data, handle, indent=1, default=_json_default)
        handle.write("\n")


@contextlib.contextmanager
def progress_bar(total: int, description: str, unit: str):
    """A tqdm bar on stderr (absent if tqdm is missing); yields ``update(n=1, postfix=None)``."""
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is in the cli extra
        yield lambda n=1, postfix=None: None
        return
    with tqdm(total=total, desc=description, unit=unit, leave=False, dynamic_ncols=True) as bar:
        def update(n=1, postfix=None):
            if postfix:
                bar.set_postfix_str(postfix, refresh=False)
            bar.update(n)
        yield update
