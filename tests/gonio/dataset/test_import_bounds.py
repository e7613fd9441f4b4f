"""Crafted inputs to the importers: one line naming the file and the problem, exit 2,
refused from the file's kind, size or header before its body is read; negative values and
near-grazing incidences said in the import summary."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest

from fabric_optics.cli.gonio import main
from gonio.data import read_dataset
from gonio.data.formats import errors
from gonio.data.formats.tensor import MAGIC, parse_tensor_bytes

FELT = Path(__file__).resolve().parents[3] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
#: data type codes of the tensor layout (gonio/data/formats/tensor.py docstring)
_CODES = {np.dtype(np.uint8): 1, np.dtype(np.uint32): 5, np.dtype(np.uint64): 7,
          np.dtype(np.float32): 10}


def _tensor(fields: dict[str, np.ndarray], *, shapes: dict | None = None,
            offsets: dict | None = None, pad: int = 0) -> bytes:
    """A Mitsuba tensor file; ``shapes``/``offsets`` override what the header declares."""
    shapes, offsets = shapes or {}, offsets or {}
    header = MAGIC + struct.pack("<BBI", 1, 0, len(fields))
    size = len(header) + sum(2 + len(n.encode()) + 2 + 1 + 8 + 8 * a.ndim
                             for n, a in fields.items())
    body, entries, at = b"", [], size
    for name, a in fields.items():
        shape = shapes.get(name, a.shape)
        off = offsets.get(name, at)
        entries.append(struct.pack("<H", len(name.encode())) + name.encode()
                       + struct.pack("<HBQ", len(shape), _CODES[a.dtype], off)
                       + struct.pack("<" + "Q" * len(shape), *shape))
        body += a.astype(a.dtype.newbyteorder("<")).tobytes()
        at += a.nbytes
    return header + b"".join(entries) + body + b"\0" * pad


@pytest.fixture(scope="module")
def felt_fields() -> dict[str, np.ndarray]:
    return parse_tensor_bytes(FELT.read_bytes(), FELT)


@pytest.fixture
def bytes_read(monkeypatch):
    """Total bytes the importers read (every read goes through RegularFile.read)."""
    total = [0]
    original = errors.RegularFile.read

    def counting(self, offset, n):
        out = original(self, offset, n)
        total[0] += len(out)
        return out

    monkeypatch.setattr(errors.RegularFile, "read", counting)
    return total


def _import_fails(capsys, tmp_path, fmt, path, needle) -> str:
    assert main(["import", fmt, str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert str(path) in err and needle in err, err
    assert not (tmp_path / "out").exists()
    return err


@pytest.mark.parametrize("fmt", ["rgl-bsdf", "pgii", "merl"])
def test_non_regular_files_are_refused(tmp_path, capsys, fmt):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)               # nobody writes it: a blocking open or read would hang here
    _import_fails(capsys, tmp_path, fmt, fifo, "is a FIFO (named pipe), not a regular file")
    _import_fails(capsys, tmp_path, fmt, Path("/dev/zero"), "is a character device")
    _import_fails(capsys, tmp_path, fmt, tmp_path, "is a directory")


@pytest.mark.parametrize("fmt,name", [("rgl-bsdf", "big.bsdf"), ("pgii", "big.txt"),
                                      ("merl", "big.binary")])
def test_a_5_gb_sparse_file_is_refused_from_its_size(tmp_path, capsys, bytes_read, fmt, name):
    big = tmp_path / name
    with open(big, "wb") as fh:
        fh.truncate(5 * 1024 ** 3)
    _import_fails(capsys, tmp_path, fmt, big, "file is 5368709120 bytes")
    assert bytes_read[0] == 0


def test_merl_header_and_fixed_size_are_checked_before_the_body(tmp_path, capsys, bytes_read):
    path = tmp_path / "short.binary"
    with open(path, "wb") as fh:
        fh.write(struct.pack("<3i", 90, 90, 180))
        fh.truncate(1_000_000)
    _import_fails(capsys, tmp_path, "merl", path, "expected 34992012 (truncated)")
    assert bytes_read[0] == 12
    path.write_bytes(struct.pack("<3i", 90, 90, 10**6) + b"\0" * 100)
    _import_fails(capsys, tmp_path, "merl", path, "header gives resolutions (90, 90, 1000000)")


def test_a_bsdf_declaring_100000_incidences_is_refused_from_its_header(tmp_path, capsys,
                                                                       bytes_read):
    """3.6 MB of data, declared as 100 000 incidences whose tables share the bytes."""
    n = 100_000
    theta = np.linspace(0, 1.5, n).astype(np.float32)
    fields = {"theta_i": theta, "phi_i": np.zeros(1, np.float32),
              "vndf": np.ones((1, n, 2, 2), np.float32), "luminance": np.ones(200, np.float32)}
    data = _tensor(fields, shapes={"luminance": (1, n, 2, 2)},
                   offsets={"luminance": 200})       # points into the vndf's data
    path = tmp_path / "many.bsdf"
    path.write_bytes(data + b"\0" * (3_600_000 - len(data)))
    err = _import_fails(capsys, tmp_path, "rgl-bsdf", path, "byte offset")
    assert "overlap" in err or "outside the data" in err
    assert bytes_read[0] < 1024                     # the header only
    # without overlapping tables: refused by the incidence bound, still from the header
    path.write_bytes(_tensor({"theta_i": theta, "phi_i": np.zeros(1, np.float32)}))
    bytes_read[0] = 0
    _import_fails(capsys, tmp_path, "rgl-bsdf", path,
                  "field 'theta_i' declares 100000 incidence angles, more than 1024")
    assert bytes_read[0] < 1024


def test_a_field_of_shape_0_by_2_to_the_64_is_one_line(tmp_path, capsys):
    path = tmp_path / "shape.bsdf"
    header = (MAGIC + struct.pack("<BBI", 1, 0, 1) + struct.pack("<H", 7) + b"theta_i"
              + struct.pack("<HBQ", 3, 10, 64) + struct.pack("<3Q", 0, 2**64 - 1, 3))
    path.write_bytes(header + b"\0" * 16)
    _import_fails(capsys, tmp_path, "rgl-bsdf", path,
                  "field 'theta_i' declares shape [0, 18446744073709551615, 3]")


def _felt_variant(tmp_path, felt_fields, name, **changes) -> Path:
    fields = {k: v.copy() for k, v in felt_fields.items()}
    fields.update(changes)
    path = tmp_path / name
    path.write_bytes(_tensor(fields))
    return path


def test_three_phi_i_1e_30_apart_is_one_line(tmp_path, capsys, felt_fields):
    f = felt_fields
    rep = {k: np.repeat(f[k], 3, axis=0) for k in ("vndf", "luminance", "rgb")}
    path = _felt_variant(tmp_path, f, "aniso.bsdf", phi_i=np.array([0, 1e-30, 2e-30], np.float32),
                         **rep)
    _import_fails(capsys, tmp_path, "rgl-bsdf", path, "field 'phi_i' spans")


@pytest.mark.parametrize("value", ["1e308", "-10", "360.5"])
def test_pgii_inphi_out_of_range_is_one_line(tmp_path, capsys, value):
    path = tmp_path / "s.txt"
    path.write_text(f"#intheta 30\n#inphi {value}\n#format: theta phi BSDF\n0 0 0.1\n10 0 0.1\n")
    _import_fails(capsys, tmp_path, "pgii", path, "line 2: #inphi")


def test_negative_bsdf_values_are_kept_and_said_per_channel(tmp_path, capsys, felt_fields):
    rgb = felt_fields["rgb"].copy()
    assert not np.any(rgb < 0)
    rgb[:, :, 0, :3, :] = -0.01            # R: 3 rows of every table
    rgb[:, :, 2, 0, :5] = -0.02            # B: 5 entries of every table
    n_r, n_b = int(np.count_nonzero(rgb[:, :, 0] < 0)), int(np.count_nonzero(rgb[:, :, 2] < 0))
    per = rgb[:, :, 0].size
    path = _felt_variant(tmp_path, felt_fields, "neg.bsdf", rgb=rgb)
    assert main(["import", "rgl-bsdf", str(path), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    note = next(line for line in out.splitlines() if "negative values kept" in line)
    assert f"R: {n_r} of {per} stored values" in note and f"B: {n_b} of {per} stored values" in note
    assert "G:" not in note
    prov = read_dataset(tmp_path / "o").meta["provenance"]["negative_values"]
    assert set(prov) == {"R", "B"} and prov["R"]["stored"] == n_r


def test_near_grazing_incidences_are_dropped_unless_kept(tmp_path, capsys):
    assert main(["import", "rgl-bsdf", str(FELT), "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "note: dropped 243 rows at near-grazing incidence (theta_i 89.999996 deg >= 89)" in out
    dropped = read_dataset(tmp_path / "d")
    assert dropped.table.theta_i.max() < 89
    assert dropped.meta["provenance"]["grazing_dropped"]["rows"] == 243
    assert main(["import", "rgl-bsdf", str(FELT), "--out", str(tmp_path / "k"),
                 "--keep-grazing"]) == 0
    kept = read_dataset(tmp_path / "k")
    assert len(kept.table) == len(dropped.table) + 243
    assert "grazing_dropped" not in kept.meta["provenance"]
    # only grazing incidences asked for: nothing left, one line naming the flag
    plan = tmp_path / "grazing.toml"
    plan.write_text('name = "g"\n[sample]\nname = "g"\n[wavelengths]\nlist_nm = [550]\n'
                    '[geometry]\nincidence_deg = [89.5]\nin_plane_deg = [0, 10]\n'
                    'skip_blocked = true\n')
    assert main(["import", "rgl-bsdf", str(FELT), "--geometry", str(plan),
                 "--out", str(tmp_path / "g")]) == 2
    assert "add --keep-grazing" in capsys.readouterr().err
