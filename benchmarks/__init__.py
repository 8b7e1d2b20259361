"""Speed and memory benchmarks of kalmix against filterpy and simdkalman.

The code is :mod:`kalmix.benchmarking` (inside the package, so that ``kalmix bench``
works from an installed copy); ``python -m benchmarks`` is a thin wrapper around it.
"""
