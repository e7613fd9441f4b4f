"""Crafted inputs of issue 23: each is one line naming the file or field, exit 2, bounded memory and time.

Every case here used to allocate gigabytes (or raise a traceback) before any check; the bounds
are :data:`simulate.fabric.weave.MAX_TRIANGLES`, :data:`simulate.fabric.weave.MAX_WEAVE_CELLS`,
:data:`simulate.fabric.wif.MAX_WIF_BYTES` and the others named in each test.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from simulate.cli import main
from simulate.fabric.mesh import mesh
from simulate.fabric.weave import MAX_TRIANGLES, MAX_WEAVE_CELLS, Weave, WeaveError, preset, triangle_count
from simulate.fabric.wif import MAX_WIF_BYTES, read_wif

PRESETS_PLAIN = [[1, 0], [0, 1]]

BASE = """
[fiber]
radius_um = 8.0
n_host = 1.557
[medium]
mu_s = 1.0
mu_a = 0.01
g = 0.8
[surface]
rms_slope = 0.3
"""


def _one_line_exit_2(capsys, argv: list[str], *needles: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


def _wif(tmp_path: Path, weaving: str = "Shafts=2\nTreadles=2", warp: str = "Threads=2", weft: str = "Threads=2",
         threading: str = "1=1\n2=2", extra: str = "[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n") -> Path:
    path = tmp_path / "crafted.wif"
    path.write_text(f"[WIF]\nVersion=1.1\n[WEAVING]\n{weaving}\n[WARP]\n{warp}\n[WEFT]\n{weft}\n"
                    f"[THREADING]\n{threading}\n{extra}")
    return path


# ------------------------------------------------------------------------------------------
# item 1: WIF and [weave] sizes


def test_wif_huge_shaft_count_allocates_nothing(tmp_path):
    # Shafts=1e10 used to build the set of every shaft (2.5 GB); it only bounds the numbers named.
    # A sinking shed needs "the other shafts": the drawdown must still be the plain weave's complement.
    rising = read_wif(_wif(tmp_path, weaving="Shafts=10000000000\nTreadles=2"))
    assert rising.tolist() == [[1, 0], [0, 1]]
    sinking = read_wif(_wif(tmp_path, weaving="Shafts=10000000000\nTreadles=2\nRising Shed=false"))
    assert sinking.tolist() == [[0, 1], [1, 0]]


@pytest.mark.parametrize("warp, weft", [("Threads=1000000000", "Threads=2"), ("Threads=30000", "Threads=30000")])
def test_wif_thread_counts_bounded_before_allocation(tmp_path, warp, weft):
    with pytest.raises(WeaveError) as info:
        read_wif(_wif(tmp_path, warp=warp, weft=weft))
    message = str(info.value)
    assert "crafted.wif" in message and "crossings" in message and f"{MAX_WEAVE_CELLS:,}" in message


def test_wif_undeclared_thread_number_is_bounded(tmp_path):
    # no [WARP] Threads: the count is the largest thread number named, here 1e9
    path = _wif(tmp_path, warp="Units=centimeters", threading="1=1\n1000000000=2")
    with pytest.raises(WeaveError, match="crossings"):
        read_wif(path)


def test_wif_largest_accepted_drawdown_reads(tmp_path):
    # exactly at the bound: MAX_WEAVE_CELLS = 2 x n picks is read (and is then too big to mesh finely)
    n = MAX_WEAVE_CELLS // 2
    treadling = "\n".join(f"{i}={1 + i % 2}" for i in range(1, n + 1))
    m = read_wif(_wif(tmp_path, weft=f"Threads={n}", extra=f"[TIEUP]\n1=1\n2=2\n[TREADLING]\n{treadling}\n"))
    assert m.shape == (2, n)
    assert m[:, 0].tolist() == [0, 1] and m[:, 1].tolist() == [1, 0]   # pick 1: treadle 2 lifts shaft 2


def test_wif_file_size_and_kind(tmp_path):
    big = tmp_path / "big.wif"
    with open(big, "wb") as f:          # sparse: no disk used
        f.truncate(MAX_WIF_BYTES + 1)
    with pytest.raises(WeaveError, match="16 MiB"):
        read_wif(big)
    fifo = tmp_path / "pipe.wif"
    os.mkfifo(fifo)
    with pytest.raises(WeaveError, match="not a regular file"):   # would block on open/read
        read_wif(fifo)


def test_weave_mesh_bound_counts_triangles_exactly():
    w = preset("twill", points_per_span=3, sides=5)
    assert len(mesh(w).faces) == triangle_count(w.n_warp, w.n_weft, 3, 5)


def test_weave_refuses_mesh_over_the_bound_before_building():
    # (documented limits 100000 each) -> 4 x 1e5 x 1e5 x 2 x 2 = 1.6e11 triangles (149 GiB)
    with pytest.raises(WeaveError) as info:
        preset("plain", points_per_span=100_000, sides=100_000)
    message = str(info.value)
    assert "160,000,000,000 triangles" in message and f"{MAX_TRIANGLES:,}" in message
    # one step under the bound is a weave
    sides = MAX_TRIANGLES // (4 * 4 * 2 * 2)
    assert Weave([[1, 0], [0, 1]], points_per_span=4, sides=sides).sides == sides
    with pytest.raises(WeaveError, match="triangles"):
        Weave([[1, 0], [0, 1]], points_per_span=4, sides=sides + 1)


def test_weave_400_by_400_matrix_refused_by_its_mesh():
    m = np.tile(np.array(PRESETS_PLAIN), (200, 200))       # a valid 400 x 400 weave
    with pytest.raises(WeaveError, match="81,920,000 triangles"):
        Weave(m)
    with pytest.raises(WeaveError, match="crossings"):   # past the cell bound: refused before listing it
        Weave(np.tile(m, (2, 2)))


def test_cli_weave_config_too_large_one_line(tmp_path, capsys):
    cfg = tmp_path / "huge.toml"
    cfg.write_text(BASE + "[weave]\npoints_per_span = 100000\nsides = 100000\n")
    out = tmp_path / "m.ply"
    _one_line_exit_2(capsys, ["weave", str(cfg), "--out", str(out)], "huge.toml", "triangles")
    assert not out.exists()


def test_cli_weave_wif_too_large_one_line(tmp_path, capsys):
    wif = _wif(tmp_path, warp="Threads=1000000000")
    cfg = tmp_path / "w.toml"
    cfg.write_text(BASE + f'[weave]\nwif = "{wif.name}"\n')
    _one_line_exit_2(capsys, ["weave", str(cfg), "--out", str(tmp_path / "m.ply")], "crafted.wif", "crossings")


def test_weave_export_failure_leaves_no_truncated_mesh(tmp_path, monkeypatch, capsys):
    import trimesh

    cfg = tmp_path / "c.toml"
    cfg.write_text(BASE)
    out = tmp_path / "m.ply"
    out.write_bytes(b"the user's previous mesh")

    def full_disk(self, file_obj=None, file_type=None, **kw):
        file_obj.write(b"ply\nformat binary_little_endian 1.0\n")    # a partial write, then ENOSPC
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(trimesh.Trimesh, "export", full_disk)
    _one_line_exit_2(capsys, ["weave", str(cfg), "--out", str(out), "--force"], "m.ply", "No space left")
    assert out.read_bytes() == b"the user's previous mesh"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml", "m.ply"]   # no temporary file left


def test_weave_export_interrupted_leaves_nothing(tmp_path, monkeypatch):
    import trimesh

    def interrupted(self, file_obj=None, file_type=None, **kw):
        file_obj.write(b"ply\n")
        raise KeyboardInterrupt

    monkeypatch.setattr(trimesh.Trimesh, "export", interrupted)
    with pytest.raises(KeyboardInterrupt):
        mesh(preset("plain", points_per_span=2, sides=3)).export(tmp_path / "m.obj")
    assert list(tmp_path.iterdir()) == []
