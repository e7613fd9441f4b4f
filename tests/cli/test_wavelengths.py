"""``--wavelengths``: one syntax everywhere (a list or an inclusive range), bounded, one line otherwise."""

from __future__ import annotations

import math
from itertools import pairwise

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fabric_optics.cli.common import MAX_WAVELENGTHS, parse_wavelengths
from fabric_optics.cli.simulate import main as simulate_main
from gonio.data.schema import WAVELENGTH_RANGE_NM

LO, HI = WAVELENGTH_RANGE_NM


def test_list_and_range_examples():
    assert parse_wavelengths("450,550,650") == (450.0, 550.0, 650.0)
    assert parse_wavelengths("400:700:100") == (400.0, 500.0, 600.0, 700.0)     # the stop is included
    assert parse_wavelengths("400:450:20") == (400.0, 420.0, 440.0)             # ... when on the grid
    assert parse_wavelengths("550:550:10") == (550.0,)
    fine = parse_wavelengths("400:700:0.3")                                      # 0.3 is not exact in binary
    assert len(fine) == 1001 and fine[-1] == pytest.approx(700.0)


@pytest.mark.parametrize("text, needle", [
    ("400:700:0", "STEP must be > 0"),
    ("400:700:-5", "STEP must be > 0"),
    ("400:700:1e-6", f"at most {MAX_WAVELENGTHS}"),
    ("400:700:nan", "finite"),
    ("400:inf:10", "finite"),
    ("700:400:10", "below START"),
    ("400:700", "START:STOP:STEP"),
    ("a:b:c", "three numbers"),
    ("100:700:10", f"[{LO:g}, {HI:g}] nm"),
    ("450,550,9000", f"[{LO:g}, {HI:g}] nm"),
    ("550,450", "increasing"),
    ("550,550", "increasing"),
    ("450,,650", "NM,NM"),
    ("450,nan", "finite"),
    (",".join(str(400 + k * 0.5) for k in range(MAX_WAVELENGTHS + 1)), f"at most {MAX_WAVELENGTHS}"),
])
def test_bad_wavelengths_say_what_to_do(text, needle):
    with pytest.raises(ValueError) as info:
        parse_wavelengths(text)
    assert needle in str(info.value)


@settings(max_examples=200, deadline=None)
@given(start=st.floats(LO, HI), span=st.floats(0, HI - LO), step=st.floats(0.05, 3000))
def test_range_property(start, span, step):
    """A valid range: increasing by STEP from START, never past STOP, within one STEP of it, and
    bounded; anything else is a ValueError (never a crash or a huge allocation)."""
    stop = min(start + span, HI)
    text = f"{start!r}:{stop!r}:{step!r}"
    n_expected = math.floor((stop - start) / step + 1e-9) + 1
    if n_expected > MAX_WAVELENGTHS + 1:
        with pytest.raises(ValueError, match="at most"):
            parse_wavelengths(text)
        return
    try:
        wl = parse_wavelengths(text)
    except ValueError as exc:
        assert "at most" in str(exc)
        return
    assert wl[0] == start and len(wl) <= MAX_WAVELENGTHS
    assert all(b > a for a, b in pairwise(wl))
    assert wl[-1] <= stop + 1e-6 * step and stop - wl[-1] < step * (1 + 1e-9)
    assert all(LO <= w <= HI + 1e-6 for w in wl)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(LO, HI), min_size=1, max_size=40, unique=True))
def test_list_property(values):
    """A list round-trips when it is increasing; any other order is refused."""
    text = ",".join(repr(v) for v in values)
    if values == sorted(values):
        assert parse_wavelengths(text) == tuple(values)
    else:
        with pytest.raises(ValueError, match="increasing"):
            parse_wavelengths(text)


@pytest.mark.parametrize("argv", [
    ["export", "red-cotton", "--method", "classic", "--wavelengths", "400:700:0", "--out", "x.bsdf"],
    ["export", "red-cotton", "--method", "classic", "--wavelengths", "400:700:1e-6", "--out", "x.bsdf"],
    ["fit", "red-cotton", "m", "--free", "dye", "--wavelengths", "400:700:0", "--out", "o"],
])
def test_the_commands_refuse_bad_wavelengths_with_one_line(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert simulate_main(argv) == 2       # a usage error: main returns argparse's status
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "argument --wavelengths:" in err, err
    assert not (tmp_path / "x.bsdf").exists()
