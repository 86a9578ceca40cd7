"""The engine's vector row kernels against NumPy, for every row width class they handle."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from spikegyro.snn.simd import add_rows, add_scaled, dot_rows

# Rows of 1, 2 and 4 registers (unrolled), wider multiples, and widths with a scalar rest.
WIDTHS = [1, 5, 8, 16, 20, 32, 48, 64, 80, 128, 256, 263]
DTYPES = [np.float32, np.float64]


@numba.njit
def _add_rows(target, rows, index, values, span, offset):
    add_rows(target, rows, index, values, span, offset)


@numba.njit
def _add_scaled(rows, row, index, values, span, offset):
    add_scaled(rows, row, index, values, span, offset)


@numba.njit
def _dot_rows(out, rows, index, row, span, offset):
    dot_rows(out, rows, index, row, span, offset)


def _case(width: int, dtype: type, seed: int):
    """Rows 0-9 addressed as index − 20 through entries 1-4 of an index list (the entries of
    one pixel within a step's list), with integer multipliers as event counts have."""
    rng = np.random.default_rng(seed)
    rows = rng.standard_normal((10, width)).astype(dtype)
    index = np.array([21, 27, 20, 29, 27, 23], np.int32)  # a row may repeat
    values = rng.integers(1, 4, index.size).astype(dtype)
    return rng, rows, index, values, (1, 5), 20


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("width", WIDTHS)
def test_add_rows_adds_each_product_in_turn_to_the_last_bit(width, dtype):
    rng, rows, index, values, span, offset = _case(width, dtype, width)
    target = rng.standard_normal(width).astype(dtype)
    expected = target.copy()
    for e in range(*span):  # the Numba loop it replaces: product, then sum, entry by entry
        expected = expected + values[e] * rows[index[e] - offset]
    _add_rows(target, rows, index, values, span, offset)
    np.testing.assert_array_equal(target, expected)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("width", WIDTHS)
def test_add_scaled_adds_the_scaled_row_to_each_entrys_row(width, dtype):
    rng, rows, index, values, span, offset = _case(width, dtype, width + 1)
    row = rng.standard_normal(width).astype(dtype)
    expected = rows.astype(np.float64)
    for e in range(*span):
        expected[index[e] - offset] += values[e] * row.astype(np.float64)
    _add_scaled(rows, row, index, values, span, offset)
    tolerance = 1e-6 if dtype == np.float32 else 1e-14  # of values near 1 (a cancelling sum)
    np.testing.assert_allclose(rows, expected, rtol=tolerance, atol=tolerance)
    untouched = sorted(set(range(10)) - {index[e] - offset for e in range(*span)})
    np.testing.assert_array_equal(rows[untouched], expected[untouched])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("width", WIDTHS)
def test_dot_rows_adds_each_entrys_dot_product_to_its_slot(width, dtype):
    rng, rows, index, _, span, offset = _case(width, dtype, width + 2)
    row = rng.standard_normal(width).astype(dtype)
    out = rng.standard_normal(span[1] - span[0] + 2).astype(dtype)
    expected = out.astype(np.float64)
    for e in range(*span):
        expected[e - span[0]] += rows[index[e] - offset].astype(np.float64) @ row
    _dot_rows(out, rows, index, row, span, offset)
    tolerance = (1e-5 if dtype == np.float32 else 1e-13) * np.sqrt(width)
    np.testing.assert_allclose(out, expected, rtol=tolerance, atol=tolerance)


def test_an_empty_span_changes_nothing():
    _, rows, index, values, _, offset = _case(32, np.float32, 0)
    target, out, row = np.ones(32, np.float32), np.ones(4, np.float32), np.ones(32, np.float32)
    before = rows.copy()
    _add_rows(target, rows, index, values, (3, 3), offset)
    _add_scaled(rows, row, index, values, (3, 3), offset)
    _dot_rows(out, rows, index, row, (3, 3), offset)
    assert (target == 1).all() and (out == 1).all()
    np.testing.assert_array_equal(rows, before)


def test_rows_that_are_not_contiguous_are_refused_at_compile_time():
    _, rows, index, values, span, offset = _case(32, np.float32, 0)
    with pytest.raises(numba.core.errors.TypingError):
        _add_rows(np.zeros(64, np.float32)[::2], rows, index, values, span, offset)
