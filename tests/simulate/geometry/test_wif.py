"""simulate.geometry.wif.read_wif: drawdowns of WIF 1.1 files, and one error line naming file and line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simulate.geometry.weave import WeaveError
from simulate.geometry.wif import read_wif, weave_from_wif

DATA = Path(__file__).parent / "data"
TWILL = [[1, 0, 0, 1], [1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 1, 1]]

HEAD = "[WIF]\nVersion=1.1\n"
WEAVING = "[WEAVING]\nShafts=2\nTreadles=2\n"
PLAIN_BODY = "[THREADING]\n1=1\n2=2\n[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n"


def _write(tmp_path, text, name="bad.wif"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_fixtures_give_the_expected_drawdowns():
    plain = read_wif(DATA / "plain.wif")
    assert plain.dtype == np.int8 and plain.tolist() == [[1, 0], [0, 1]]
    assert read_wif(DATA / "twill.wif").tolist() == TWILL
    # the same twill as a lift plan, lower-case names, comments after values
    assert read_wif(str(DATA / "twill-liftplan.wif")).tolist() == TWILL


def test_twill_fixture_is_a_2_2_twill():
    m = read_wif(DATA / "twill.wif")
    assert (m.sum(axis=0) == 2).all() and (m.sum(axis=1) == 2).all()
    # each pick is the previous one shifted by one warp thread: a twill line
    for i in range(1, 4):
        assert np.array_equal(m[:, i], np.roll(m[:, i - 1], 1))


def test_weave_from_wif_passes_params():
    w = weave_from_wif(DATA / "twill.wif", spacing_um=200, width_um=150, height_um=50, sides=5)
    assert w.matrix.tolist() == TWILL and (w.spacing_um, w.sides) == (200.0, 5)


def test_sinking_shed_inverts_the_tieup(tmp_path):
    path = _write(tmp_path, HEAD + "[WEAVING]\nShafts=2\nTreadles=2\nRising Shed=false\n" + PLAIN_BODY)
    assert read_wif(path).tolist() == [[0, 1], [1, 0]]


def test_counts_from_warp_and_weft_sections_and_multiple_treadles(tmp_path):
    # 3 warp threads (thread 3 on both shafts), picks 1..3; pick 3 presses both treadles
    text = (HEAD + WEAVING + "[WARP]\nThreads=3\n[WEFT]\nThreads=3\n[THREADING]\n1=1\n2=2\n3=1,2\n"
            "[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n3=1,2\n")
    assert read_wif(_write(tmp_path, text)).tolist() == [[1, 0, 1], [0, 1, 1], [1, 1, 1]]


@pytest.mark.parametrize("text,message", [
    (HEAD + WEAVING + "[THREADING]\n1=1\nthis is not ini\n", "bad.wif, line 8: cannot parse 'this is not ini'"),
    ("Version=1.1\n" + HEAD, "bad.wif, line 1: 'Version=1.1' comes before any [SECTION] header"),
    ("[WEAVING]\nShafts=2\n", "bad.wif: no [WIF] section; not a Weaving Information File"),
    (HEAD + WEAVING + "[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n", "bad.wif: no [THREADING] section"),
    (HEAD + "[THREADING]\n1=1\n", "bad.wif: no [WEAVING] section"),
    (HEAD + WEAVING + "[THREADING]\n1=1\n2=2\n", "no [LIFTPLAN] and no [TIEUP] + [TREADLING] sections"),
    (HEAD + WEAVING + "[THREADING]\n1=1\n2=2\n[TIEUP]\n1=1\n2=2\n", "bad.wif: no [TREADLING] section"),
    (HEAD + WEAVING + "[THREADING]\n1=1\n2=3\n[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n",
     "bad.wif, line 8: [THREADING] thread 2 references shaft 3, but [WEAVING] Shafts=2"),
    (HEAD + WEAVING + "[THREADING]\n1=1\n2=2\n[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=5\n",
     "bad.wif, line 14: [TREADLING] pick 2 references treadle 5, but [WEAVING] Treadles=2"),
    (HEAD + WEAVING + "[THREADING]\n1=1\n2=2\n[TIEUP]\n1=1\n3=2\n[TREADLING]\n1=1\n2=2\n",
     "bad.wif, line 11: [TIEUP] treadle 3 out of range (1..2)"),
    (HEAD + WEAVING + "[WARP]\nThreads=2\n[THREADING]\n1=1\n3=2\n[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n",
     "bad.wif, line 10: [THREADING] thread 3 out of range (1..2)"),
    (HEAD + WEAVING + "[THREADING]\n1=1\n1=2\n", "bad.wif, line 8: [THREADING] 1 repeated (first on line 7)"),
    (HEAD + WEAVING + "[THREADING]\none=1\n", "bad.wif, line 7: [THREADING] key 'one' must be a thread number"),
    (HEAD + WEAVING + "[THREADING]\n1=a\n", "bad.wif, line 7: [THREADING] thread 1: shaft 'a' is not a number"),
    (HEAD + "[WEAVING]\nShafts=two\n" + PLAIN_BODY, "bad.wif, line 4: [WEAVING] shafts must be an integer"),
    (HEAD + "[WEAVING]\nTreadles=2\n" + PLAIN_BODY, "bad.wif, line 3: [WEAVING] has no Shafts= entry"),
    (HEAD + "[WEAVING]\nShafts=2\n" + PLAIN_BODY, "[WEAVING] has no Treadles= entry"),
    (HEAD + "[WEAVING]\nShafts=2\nTreadles=2\nRising Shed=maybe\n" + PLAIN_BODY,
     "bad.wif, line 6: [WEAVING] rising shed must be true or false"),
    (HEAD + WEAVING + "[LIFTPLAN]\n1=1\n", "bad.wif: no [THREADING] section"),
    (HEAD + WEAVING + "[THREADING]\n1=1\n2=2\n[LIFTPLAN]\n1=1\n2=9\n",
     "bad.wif, line 11: [LIFTPLAN] pick 2 references shaft 9, but [WEAVING] Shafts=2"),
])
def test_bad_wif_is_one_error_naming_file_and_line(tmp_path, text, message):
    with pytest.raises(WeaveError) as exc:
        read_wif(_write(tmp_path, text))
    assert message in str(exc.value), str(exc.value)
    assert "\n" not in str(exc.value)


def test_missing_file(tmp_path):
    with pytest.raises(WeaveError, match="nothing.wif: cannot read the WIF file"):
        read_wif(tmp_path / "nothing.wif")


def test_a_drawdown_that_does_not_interlace_names_the_file(tmp_path):
    # thread 2 is on shaft 2, which no treadle lifts: warp row 1 never rises
    text = HEAD + WEAVING + "[THREADING]\n1=1\n2=2\n[TIEUP]\n1=1\n2=1\n[TREADLING]\n1=1\n2=\n"
    path = _write(tmp_path, text, "float.wif")
    assert read_wif(path).tolist() == [[1, 0], [0, 0]]
    with pytest.raises(WeaveError, match=r"float\.wif: weave matrix: warp row 1 never interlaces \(all 0\) "
                                         r"\(row j = warp thread j \+ 1"):
        weave_from_wif(path)
