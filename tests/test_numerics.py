"""Discrete choices and written floats that do not follow the last bits of a float (issue 30 item 4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from robocal.io import reproducible, to_json, tracked_float
from robocal.numerics import argmax_tied, column_norms, sorted_tied


def test_a_tie_up_to_rounding_goes_to_the_first_candidate() -> None:
    # two scores equal in exact arithmetic, apart by rounding noise in either direction (another BLAS kernel)
    a = np.array([1.0, 3.0, 3.0 * (1 + 4e-16), 2.0])
    b = np.array([1.0, 3.0 * (1 + 4e-16), 3.0, 2.0])
    assert int(np.argmax(a)) != int(np.argmax(b))  # what a plain argmax does
    assert argmax_tied(a) == argmax_tied(b) == 1
    assert argmax_tied([0.0, 1.0, 1.0 + 1e-6]) == 2  # a real difference (1e-6 >> 1e-8 relative) still wins


def test_sorted_tied_keeps_input_order_among_ties() -> None:
    items = ["a", "b", "c", "d"]
    k1 = {"a": -5.0, "b": -5.0 * (1 + 1e-15), "c": -7.0, "d": -1.0}
    k2 = {"a": -5.0 * (1 + 1e-15), "b": -5.0, "c": -7.0, "d": -1.0}
    assert sorted_tied(items, k1.__getitem__) == sorted_tied(items, k2.__getitem__) == ["c", "a", "b", "d"]
    assert sorted_tied([], float) == []
    with pytest.raises(ValueError, match="empty"):
        argmax_tied([])


@pytest.mark.parametrize("shape", [(4096, 5), (4097, 7), (12_510, 90), (20_000, 3)])
def test_column_norms_are_numpys_bit_for_bit(shape: tuple[int, int]) -> None:
    # the chunked sum (no (M, k) temporaries: the fits' column scales and identifiability) is np.linalg.norm's
    rng = np.random.default_rng(shape[0])
    A = rng.standard_normal(shape) * rng.uniform(1e-6, 1e3, shape[1])
    assert np.array_equal(column_norms(A), np.linalg.norm(A, axis=0))
    F = np.asfortranarray(A)  # another layout: numpy's own
    assert np.array_equal(column_norms(F), np.linalg.norm(F, axis=0))


def test_tracked_floats_drop_the_noise_and_keep_the_model() -> None:
    # a numerical leftover at machine precision is zero; noise under the precision does not change the text
    assert tracked_float(2.87e-16, "leftover") == tracked_float(3.1e-17, "leftover") == 0.0
    assert tracked_float(-0.0801985299, "log10_p") == tracked_float(-0.0802066528 + 7e-6, "log10_p")
    assert tracked_float(-0.00148168255, "cv_gain") == tracked_float(-0.00148153609, "cv_gain")
    assert str(tracked_float(-1e-13, "rms_mm")) == "0.0"  # no "-0.0" in a file
    # a model value keeps its 9 significant digits (a link length to 1e-6 mm, an angle to 1e-9 rad)
    assert tracked_float(1234.56789123, "value") == 1234.56789
    # ... at no more than 12 decimals: a small kinematic error's last digit is absolute noise (Sandybridge kernel)
    assert tracked_float(8.51680062e-06, "alpha4") == tracked_float(8.51680063e-06, "alpha4") == 8.516801e-06
    assert tracked_float(3e-15, "covariance") == 3e-15  # legitimately tiny quantities keep their digits
    with reproducible():
        text = to_json({"eliminated": [{"leftover": 5.9e-16}], "p": {"value": 0.123456789123}, "rms_mm": 0.01234567})
    assert json.loads(text) == {"eliminated": [{"leftover": 0.0}], "p": {"value": 0.123456789}, "rms_mm": 0.012346}


def test_an_estimate_is_written_to_its_standard_errors_precision() -> None:
    """A poorly determined coefficient's 9th digit is kernel noise (a thermal drift 0.00101883632 vs ...633 under
    Prescott and Haswell, stderr 0.0035): an estimate (value, stderr, unit) keeps its value to the standard error's
    third significant digit, the same text either way; a model parameter (more keys) keeps its 9 digits."""
    with reproducible():
        a, b = (
            json.loads(to_json({"value": v, "stderr": 0.0035154, "unit": "mm/degC"}))
            for v in (0.00101883632, 0.00101883633)
        )
        par = json.loads(to_json({"name": "a2", "value": 0.00101883632, "stderr": 0.0035154, "unit": "mm"}))
    assert a == b and a["value"] == 0.00102 and a["stderr"] == 0.0035154
    assert par["value"] == 0.00101883632
    assert json.loads(to_json({"value": 0.00101883632, "stderr": 0.0035154, "unit": "mm"}))["value"] == 0.00101883632
