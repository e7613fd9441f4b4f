"""pgII values below zero (gonio.data.formats.pgii, "Negative values"): noise around zero is kept, counted and
said; a value further below zero than NEGATIVE_NOISE of its column's largest value is refused naming the line."""

from __future__ import annotations

import pytest

from fabric_optics.cli.gonio import main as gonio_main
from gonio.data import read_dataset
from gonio.data.formats import FormatError, import_notes
from gonio.data.formats.pgii import NEGATIVE_NOISE, parse_pgii, pgii_dataset


def _text(rows, lam="#lambda=450 650\n"):
    return "#sample_name \"felt\"\n#intheta 30\n#format: theta phi BSDF\n" + lam + "".join(
        " ".join(f"{v:.10g}" for v in r) + "\n" for r in rows)


ROWS = [(0, 0, 0.10, 0.20), (20, 0, 0.40, 0.30), (60, 0, -0.004, 0.02), (80, 0, -0.019, -0.001)]


def test_noise_below_zero_is_kept_and_counted(caplog):
    f = parse_pgii(_text(ROWS), "a.txt")
    with caplog.at_level("WARNING"):
        ds = pgii_dataset([f])
    neg = ds.meta["provenance"]["negative_values"]
    assert neg == {"450": {"stored": 2, "of": 4, "rows": 2}, "650": {"stored": 1, "of": 4, "rows": 1}}
    assert (ds.table["beta"] < 0).sum() == 3                            # kept as stored (x pi), not clipped
    assert "negative values kept as stored (measurement noise around zero)" in import_notes(ds)[0]
    assert any("negative values kept" in r.getMessage() for r in caplog.records)


def test_a_value_beyond_the_noise_bound_is_refused_naming_the_line():
    # 450 nm peaks at 0.4: the bound is -0.02; -0.021 is beyond it (line 8: the 4th data line)
    rows = ROWS[:3] + [(80, 0, -0.021, 0.0)]
    with pytest.raises(FormatError) as err:
        parse_pgii(_text(rows), "a.txt")
    text = str(err.value)
    assert "a.txt" in text and "line 8" in text and "-0.021 (450 nm)" in text and f"{NEGATIVE_NOISE:g}" in text


def test_a_column_of_negative_values_only_is_refused():
    with pytest.raises(FormatError, match=r"value -0.1 \(Y\) is negative and no value of that column is above zero"):
        parse_pgii(_text([(0, 0, -0.1), (20, 0, -0.05)], lam=""), "y.txt")


def test_gonio_import_says_so_and_refuses_with_exit_2(tmp_path, capsys):
    (tmp_path / "a.txt").write_text(_text(ROWS))
    assert gonio_main(["import", "pgii", str(tmp_path / "a.txt"), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "note: negative values kept as stored" in out and "450: 2 of 4" in out
    assert read_dataset(tmp_path / "o").meta["provenance"]["negative_values"]["650"]["stored"] == 1
    (tmp_path / "b.txt").write_text(_text([(0, 0, 0.1, 0.2), (20, 0, -5.0, 0.1)]))
    assert gonio_main(["import", "pgii", str(tmp_path / "b.txt"), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "b.txt" in err and "further below zero than measurement noise" in err
    assert not (tmp_path / "p").exists()
