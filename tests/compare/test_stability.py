"""docs/quality.md section B for the compare layer: a bad normal value or an empty dataset is a
clear error naming what is wrong, never a silent NaN in the metrics."""

from __future__ import annotations

import numpy as np
import pytest

from compare.comparison import compare_datasets
from compare.errors import CompareError
from gonio.data.dataset import DatasetError


@pytest.mark.parametrize("value, error, words", [
    (np.nan, DatasetError, ["column 'beta'", "finite"]),
    (np.inf, DatasetError, ["column 'beta'", "finite"]),
    (-0.1, CompareError, ["normal/normal", "positive finite"]),
    (0.0, CompareError, ["normal/normal", "positive finite"]),
])
def test_a_bad_value_next_to_the_normal_is_named(h, value, error, words):
    table = h.in_plane_table(h.red_lobe)
    measured = h.dataset(table)
    bad = table.copy()
    # the normal/normal value is estimated from the normal-incidence neighbours: spoil them
    near = (bad["theta_i"] == 0.0) & (bad["theta_o"] <= 10.0)
    bad.loc[near, "beta"] = value
    with pytest.raises(error) as info:
        compare_datasets(measured, [h.dataset(bad, kind="simulated", name="bad")])
    assert all(w in str(info.value) for w in words), str(info.value)


def test_an_empty_dataset_is_refused(h):
    with pytest.raises(DatasetError, match="no data rows"):
        h.dataset(h.in_plane_table(h.red_lobe).iloc[:0])


def test_good_data_gives_finite_metrics(h):
    table = h.in_plane_table(h.red_lobe)
    c = compare_datasets(h.dataset(table), [h.dataset(table.copy(), kind="simulated", name="same")])
    flat = [v for v in _numbers(c.metrics())]
    assert flat and all(np.isfinite(flat))


def _numbers(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _numbers(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from _numbers(v)
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield float(obj)
