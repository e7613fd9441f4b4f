"""simulate bench's fabric part (fabric_optics.bench.fabric): whole processes on cold and warm table caches.

Not a timing test: it checks that a warm cache is really used by a separate process (the
tables load, the result is the same number) and that the report carries what it promises.
"""

from __future__ import annotations

import math
import os

import pytest

from fabric_optics.bench import fabric as bench_fabric


@pytest.mark.slow  # five whole `simulate fabric` processes
def test_fabric_bench_cold_and_warm_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("FABRIC_OPTICS_CACHE_DIR", str(tmp_path / "mine"))
    report = bench_fabric.run_fabric_bench(repeats=1, target=0.2, in_process=False)
    whole = report["whole_process"]
    cold, warm = whole["mc_cold"]["runs"][0], whole["mc_warm"]["runs"][0]
    assert cold["table_cache"] == ["miss", "miss"] and warm["table_cache"] == ["hit", "hit"]
    assert warm["rel_err"] == cold["rel_err"] and 0 < cold["rel_err"] < 1   # the same tables, the same result
    assert whole["summation"]["runs"][0]["table_cache"] is None
    for key in ("summation", "mc_cold", "mc_warm"):
        w = whole[key]
        assert math.isfinite(w["median_wall_seconds"]) and w["median_cpu_seconds"] > 0
        assert w["target_seconds"] == bench_fabric.TARGETS_SECONDS[key]
    assert not (tmp_path / "mine").exists()                      # the bench kept off the caller's cache
    assert os.environ["FABRIC_OPTICS_CACHE_DIR"] == str(tmp_path / "mine")
    assert "mc, warm table cache" in bench_fabric.markdown(report)
