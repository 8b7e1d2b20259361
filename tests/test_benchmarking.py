"""The benchmark harness runs end to end at toy sizes (no timings are asserted)."""

import json

import pytest

from kalmix import benchmarking as bench

pytest.importorskip("numba")


def test_benchmark_sections_fill_the_json_shape_and_write_the_figure(tmp_path):
    pytest.importorskip("filterpy")
    pytest.importorskip("simdkalman")
    results = dict(quick=True, machine=bench.machine_peak())
    results["single_stream"] = bench.bench_single_stream(steps=20, imm_steps=3, numpy_steps=3, repeats=1)
    results["batch"] = bench.bench_batch([1, 3], budget=400, repeats=1)
    results["plain_kf"] = bench.bench_plain_kf(series=8, steps=30, repeats=1)
    results["scaling"] = bench.bench_scaling([1, 8], [1, 2], steps=10, repeats=1)
    results["physical"] = bench.physical_limits(results)

    single, batch, plain = results["single_stream"], results["batch"], results["plain_kf"]
    assert single["kalmix_steps_per_s"] > 0 and single["filterpy_imm40_steps_per_s"] > 0
    assert batch["targets"] == [1, 3] and len(batch["expert_steps_per_s"]) == 2
    assert all(mb > 0 for mb in batch["peak_mb_per_target"])
    # the plain-filter comparison runs the same model as simdkalman: same predictions
    assert plain["max_rel_difference"] < 1e-9
    assert plain["simdkalman_series_steps_per_s"] > 0

    table = bench.markdown_table(results)
    assert "| (a) one stream" in table and "simdkalman" in table
    png = tmp_path / "perf.png"
    bench.plot(results, png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    json.dumps(bench._json_ready(results))  # serialisable
