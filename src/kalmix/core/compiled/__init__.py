"""The compiled engine (numba): same numbers as the numpy spec, used by every command.

Importing a kernel module first points numba's on-disk cache at a directory keyed on
a hash of every compiled source of kalmix (and the numba version), so an edited
kernel, or an edited helper it inlines from another file, is never served stale from
a warm cache (numba's own cache checks only the time stamp of the decorated
function's file). The directory is ``$KALMIX_CACHE_DIR`` if set, else
``<user cache>/kalmix/numba-<hash>``.
"""

from ._cache import cache_directory, configure_cache, numba_available

__all__ = ["cache_directory", "configure_cache", "numba_available"]
