"""The table cache (simulate.fiber.tablecache): keys, hits, atomic concurrent writes, the size bound, corruption.

Every test uses its own directory through ``FABRIC_OPTICS_CACHE_DIR`` (and the root conftest
points the whole suite at a temporary one): the user's cache is never touched.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from simulate.fiber import tablecache as tc


@pytest.fixture
def cache(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv(tc.ENV_DIR, str(d))
    monkeypatch.delenv(tc.ENV_DISABLE, raising=False)
    monkeypatch.delenv(tc.ENV_MAX_BYTES, raising=False)
    return d


@dataclasses.dataclass(frozen=True)
class _Medium:
    mu_s: float
    table: np.ndarray


def test_the_suite_runs_on_a_private_cache():
    home_cache = Path.home() / ".cache" / "fabric-optics"
    assert tc.cache_dir() != home_cache
    assert "fabric-optics-test-cache-" in os.environ[tc.ENV_DIR]


def test_cache_dir_defaults_follow_xdg(monkeypatch, tmp_path):
    monkeypatch.delenv(tc.ENV_DIR, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert tc.cache_dir() == tmp_path / "xdg" / "fabric-optics"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert tc.cache_dir() == Path.home() / ".cache" / "fabric-optics"


def test_key_changes_with_every_input_and_not_with_equal_content():
    mods = ("simulate.fiber.tablecache",)
    base = {"medium": _Medium(0.8, np.array([1.0, 2.0])), "seed": 3, "grid": (3, 2.0)}
    same = {"grid": (3, 2.0), "seed": 3, "medium": _Medium(0.8, np.array([1.0, 2.0]))}
    k = tc.content_key("yarn", base, mods)
    assert tc.content_key("yarn", same, mods) == k
    changed = [
        {**base, "medium": _Medium(0.8000001, np.array([1.0, 2.0]))},
        {**base, "medium": _Medium(0.8, np.array([1.0, 2.5]))},
        {**base, "medium": _Medium(0.8, np.array([1.0, 2.0], dtype=np.float32))},
        {**base, "seed": 4},
        {**base, "grid": (3, 2.0, 1)},
    ]
    keys = {tc.content_key("yarn", c, mods) for c in changed}
    assert k not in keys and len(keys) == len(changed)
    assert tc.content_key("albedo", base, mods) != k
    assert tc.content_key("yarn", base, ("simulate.fiber.tablecache", "simulate.fiber.spectral")) != k


def test_objects_without_a_canonical_form_are_refused():
    with pytest.raises(TypeError, match="no canonical form"):
        tc.content_hash({"f": object()})


def test_hit_is_bit_identical_to_the_miss(cache):
    rng = np.random.default_rng(1)
    calls = []

    def compute():
        calls.append(1)
        return {"T": rng.random((3, 4, 5)), "n": np.int64(7), "f32": rng.random(6).astype(np.float32)}

    miss, hit0 = tc.cached("yarn-abc", compute)
    got, hit1 = tc.cached("yarn-abc", compute)
    assert (hit0, hit1) == (False, True) and len(calls) == 1
    for name in miss:
        assert got[name].dtype == miss[name].dtype
        assert got[name].tobytes() == miss[name].tobytes()


def test_disabled_cache_neither_reads_nor_writes(cache, monkeypatch):
    monkeypatch.setenv(tc.ENV_DISABLE, "1")
    a, hit = tc.cached("yarn-x", lambda: {"a": np.ones(3)})
    b, hit2 = tc.cached("yarn-x", lambda: {"a": np.zeros(3)})
    assert not hit and not hit2 and b["a"].sum() == 0
    assert not cache.exists() or not list(cache.iterdir())


def test_a_corrupted_entry_is_detected_deleted_and_recomputed(cache):
    tc.store("yarn-c", {"a": np.arange(1000.0)})
    path = cache / ("yarn-c" + tc.SUFFIX)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01                       # one flipped bit in the payload
    path.write_bytes(bytes(data))
    assert tc.load("yarn-c") is None and not path.exists()
    tc.store("yarn-c", {"a": np.arange(1000.0)})
    path.write_bytes(path.read_bytes()[:100])          # a truncated file
    got, hit = tc.cached("yarn-c", lambda: {"a": np.arange(1000.0) * 2})
    assert not hit and got["a"][1] == 2.0
    again, hit = tc.cached("yarn-c", lambda: {"a": np.zeros(1)})
    assert hit and np.array_equal(again["a"], np.arange(1000.0) * 2)


def test_eviction_keeps_the_bound_and_drops_the_least_recently_used(cache, monkeypatch):
    size = len(tc._MAGIC) + 32
    one = {"a": np.zeros(10_000)}                        # ~80 kB per entry
    tc.store("yarn-0", one)
    entry = tc.entries()[0][1]
    assert entry > size
    monkeypatch.setenv(tc.ENV_MAX_BYTES, str(int(3.5 * entry)))
    for i in range(1, 3):
        tc.store(f"yarn-{i}", one)
        p = cache / f"yarn-{i}{tc.SUFFIX}"
        os.utime(p, (1_000_000 + i, 1_000_000 + i))      # distinct, increasing mtimes
    os.utime(cache / f"yarn-0{tc.SUFFIX}", (1_000_000, 1_000_000))
    assert tc.load("yarn-0") is not None                 # used now: the most recent
    for i in range(3, 5):
        tc.store(f"yarn-{i}", one)
        total = sum(s for _, s, _ in tc.entries())
        assert total <= 3.5 * entry
    names = {p.name for _, _, p in tc.entries()}
    assert names == {f"yarn-{i}{tc.SUFFIX}" for i in (0, 3, 4)}   # 1 and 2 were the least recently used


def test_bad_size_bound_is_one_clear_error(monkeypatch):
    monkeypatch.setenv(tc.ENV_MAX_BYTES, "lots")
    with pytest.raises(tc.CacheError, match="FABRIC_OPTICS_CACHE_MAX_BYTES"):
        tc.max_bytes()


_WRITER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    import numpy as np
    from simulate.fiber import tablecache as tc
    ident = int(sys.argv[1])
    gate = Path(sys.argv[3])
    (gate.parent / f"ready-{ident}").touch()
    while not gate.exists():                # start together (after both imports)
        time.sleep(0.01)
    for _ in range(int(sys.argv[2])):
        tc.store("yarn-shared", {"a": np.full(300_000, float(ident)), "who": np.int64(ident)})
        got = tc.load("yarn-shared")        # a reader between the writers: whole entries only
        assert got is not None and np.all(got["a"] == got["who"]), "torn read"
    print("ok")
""")


def test_concurrent_writers_leave_one_valid_entry(cache):
    env = {**os.environ, tc.ENV_DIR: str(cache), "PYTHONPATH": str(Path(__file__).resolve().parents[3])}
    gate = cache.parent / "go"
    procs = [subprocess.Popen([sys.executable, "-c", _WRITER, str(i), "20", str(gate)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for i in (1, 2)]
    while not all((cache.parent / f"ready-{i}").exists() for i in (1, 2)) and all(p.poll() is None for p in procs):
        time.sleep(0.01)
    gate.touch()
    outs = [p.communicate(timeout=900) for p in procs]
    for p, (out, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err
        assert out.strip() == "ok"
    files = sorted(os.listdir(cache))
    assert files == ["yarn-shared" + tc.SUFFIX]          # no temporary file left, one entry
    got = tc.load("yarn-shared")
    assert got is not None and int(got["who"]) in (1, 2) and np.all(got["a"] == got["who"])


def test_eviction_is_logged_in_order_and_spares_this_run_s_own_tables(cache, monkeypatch, caplog):
    """Other runs' entries go first (least recently used first), each eviction is one INFO line naming the entry,
    its kind, size and last use; this run's own entry is kept although it is the oldest."""
    one = {"a": np.zeros(10_000)}
    for name in ("exit-own", "yarn-old", "yarn-new"):
        tc.store(name, one)
    entry = tc.entries()[0][1]
    for name, t in (("exit-own", 1_000_000), ("yarn-old", 1_000_100), ("yarn-new", 1_000_200)):
        os.utime(cache / f"{name}{tc.SUFFIX}", (t, t))
    # as if another run had made the two yarn tables: only exit-own is this process's
    monkeypatch.setattr(tc, "_USED", {str(cache / f"exit-own{tc.SUFFIX}")})
    monkeypatch.setenv(tc.ENV_MAX_BYTES, str(int(2.5 * entry)))
    with caplog.at_level("INFO", logger=tc.__name__):
        tc.store("exit-next", one)                         # 4 entries over a bound of 2.5: two go
    names = {p.name for _, _, p in tc.entries()}
    assert names == {f"exit-own{tc.SUFFIX}", f"exit-next{tc.SUFFIX}"}
    lines = [r.getMessage() for r in caplog.records if r.name == tc.__name__]
    evicted = [m.split()[3] for m in lines if m.startswith("table cache: evicted ")]
    assert evicted == [f"yarn-old{tc.SUFFIX}", f"yarn-new{tc.SUFFIX}"]          # least recently used first
    assert f"(yarn, {entry / 1e6:,.1f} MB, last used " in lines[0] and "bound of" in lines[0]
    assert any(m.startswith("table cache: 2 entries evicted") for m in lines)
    assert not any(r.levelname == "WARNING" for r in caplog.records)


def test_a_run_whose_own_tables_exceed_the_bound_says_so(cache, monkeypatch, caplog):
    one = {"a": np.zeros(10_000)}
    monkeypatch.setattr(tc, "_USED", set())
    tc.store("exit-0", one)
    entry = tc.entries()[0][1]
    monkeypatch.setenv(tc.ENV_MAX_BYTES, str(int(1.5 * entry)))
    with caplog.at_level("INFO", logger=tc.__name__):
        tc.store("exit-1", one)
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "this run's own tables" in warnings[0] and tc.ENV_MAX_BYTES in warnings[0]
    assert str(2 * entry) in warnings[0]                   # the two tables' size: the bound to set


def test_the_felt_meshes_count_in_the_bound_and_are_evicted_as_any_entry(cache, monkeypatch):
    """A felt built by simulate.geometry.felt.cached_felt_mesh is an entry like a table: its size is in the
    total the bound is held to, and it is evicted least recently used first."""
    from simulate.fabric.structure import StructureSpec
    from simulate.geometry import felt as FM

    monkeypatch.setattr(tc, "_USED", set())
    felt, hit = FM.cached_felt_mesh(StructureSpec(kind="nonwoven", felt_spread_deg=15.0, layers=1), 10.0, seed=1)
    assert not hit
    [(_, felt_size, felt_path)] = tc.entries()
    assert felt_path.name.startswith("felt-") and felt_size > felt.vertices.nbytes + felt.faces.nbytes
    os.utime(felt_path, (1_000_000, 1_000_000))          # the least recently used
    tc._USED.clear()                                     # and not this run's
    one = {"a": np.zeros(10_000)}
    tc.store("yarn-0", one)
    entry = tc.entries()[-1][1]
    # room for the felt and one table and a half: the second table is over the bound only with the felt counted
    monkeypatch.setenv(tc.ENV_MAX_BYTES, str(felt_size + int(1.5 * entry)))
    tc.store("yarn-1", one)
    assert {p.name for _, _, p in tc.entries()} == {f"yarn-0{tc.SUFFIX}", f"yarn-1{tc.SUFFIX}"}
    assert tc.evict() == 0


def test_a_flipped_bit_anywhere_gives_a_miss_or_the_same_arrays(cache, caplog):
    """Every bit position of a small entry: the read either refuses it (a miss, deleted) or returns
    the stored arrays bit for bit (the flip was in bytes that do not change what is read), never
    other arrays; and a file cut anywhere is a miss."""
    arrays = {"T": np.arange(24.0).reshape(2, 3, 4), "F": np.asfortranarray(np.arange(6, dtype=np.int32).reshape(2, 3)),
              "n": np.int64(7)}
    path = tc.store("yarn-flip", arrays)
    good = path.read_bytes()
    got = tc.load("yarn-flip")
    assert got is not None and set(got) == set(arrays)
    for name, a in arrays.items():
        assert got[name].dtype == np.asarray(a).dtype and got[name].shape == np.shape(a)
        assert np.array_equal(got[name], a) and got[name].flags.f_contiguous == np.asarray(a).flags.f_contiguous
    misses = same = 0
    for i in range(len(good)):
        for bit in (0x01, 0x80):
            data = bytearray(good)
            data[i] ^= bit
            path.write_bytes(bytes(data))
            got = tc.load("yarn-flip")
            if got is None:
                assert not path.exists()
                misses += 1
            else:
                assert set(got) == set(arrays)
                assert all(got[k].dtype == np.asarray(v).dtype and got[k].tobytes() == np.asarray(v).tobytes()
                           for k, v in arrays.items())
                same += 1
    data_bytes = sum(np.asarray(a).nbytes for a in arrays.values())
    assert misses >= 2 * data_bytes and same > 0     # every data byte's flips are caught; the digest's are harmless
    for cut in range(0, len(good), 7):
        path.write_bytes(good[:cut])
        assert tc.load("yarn-flip") is None


def test_an_entry_is_the_header_the_payload_s_digest_and_the_archive_np_savez_writes(cache, monkeypatch):
    """The entry written straight into its file is byte for byte ``MAGIC + sha256(payload) + payload``,
    ``payload`` the archive ``np.savez`` writes into memory (the zip's timestamps held fixed)."""
    import hashlib
    import io

    fixed = time.struct_time((2024, 5, 6, 7, 8, 9, 0, 127, 0))
    monkeypatch.setattr(time, "localtime", lambda *a: fixed)
    monkeypatch.setattr(tc, "_HASH_BLOCK", 1000)      # the payload read back in many blocks
    rng = np.random.default_rng(3)
    arrays = {"T": rng.random((4, 5, 300)), "F": np.asfortranarray(rng.random((7, 9))), "n": np.int64(11)}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    payload = buf.getvalue()
    path = tc.store("yarn-format", arrays)
    assert path is not None and path.read_bytes() == tc._MAGIC + hashlib.sha256(payload).digest() + payload


def test_storing_a_table_holds_no_copy_of_it(cache):
    """The archive goes to the file as it is written (numpy's blocks of 16 MiB) and is hashed from the file:
    the memory a store allocates stays far below the table's size (an archive built in memory, then joined
    to its header, held two copies beside it)."""
    import tracemalloc

    table = np.ones(8 * 2 ** 20)              # 64 MiB
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        path = tc.store("yarn-big", {"T": table})
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert path is not None and path.stat().st_size > table.nbytes
    assert peak < 0.6 * table.nbytes, f"store allocated {peak / 2 ** 20:.0f} MiB for a {table.nbytes / 2 ** 20:.0f} MiB table"
    got = tc.load("yarn-big")
    assert got is not None and np.array_equal(got["T"], table)


def test_a_finished_fit_is_evicted_after_every_table(cache, monkeypatch):
    """A finished fit's entry (a few MB standing for a whole fit) outlives the tables around it, although it is
    the least recently used: the tables go first."""
    one = {"a": np.zeros(10_000)}
    for name in ("fit-old", "yarn-a", "yarn-b"):
        tc.store(name, one)
    entry = tc.entries()[0][1]
    for name, t in (("fit-old", 1_000_000), ("yarn-a", 1_000_100), ("yarn-b", 1_000_200)):
        os.utime(cache / f"{name}{tc.SUFFIX}", (t, t))
    monkeypatch.setattr(tc, "_USED", set())                 # as if another run had made all three
    monkeypatch.setenv(tc.ENV_MAX_BYTES, str(int(2.5 * entry)))
    tc.store("yarn-next", one)                               # 4 entries over a bound of 2.5: two go
    names = {p.name for _, _, p in tc.entries()}
    assert names == {f"fit-old{tc.SUFFIX}", f"yarn-next{tc.SUFFIX}"}
    from fabric_optics.fitting import reuse

    assert tc.FIT_PREFIX == f"{reuse.KIND}-"                 # the prefix of the fits' keys
