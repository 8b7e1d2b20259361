"""Each family kind's compiled driver: the module the registry (:data:`kalmix.core.families.KINDS`) names.

Every driver module has the same parts (:mod:`.kinematic` lists them), so the CPU engine, the GPU
staged engine and the compile warm-up run any family through them, without a branch on its kind.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from ..families import parts

__all__ = ["driver"]


def driver(kind: str) -> ModuleType:
    """The compiled driver module of the family kind ``kind`` (imported on first use: it compiles with numba)."""
    return importlib.import_module(f"{__package__}.{parts(kind).compiled}")
