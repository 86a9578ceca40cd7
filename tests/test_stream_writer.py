"""Prediction files: CSV and HDF5 round trips, gyro columns, atomic writes."""

from __future__ import annotations

import numpy as np
import pytest

from spikegyro.errors import InputError
from spikegyro.events.io import read_gyro
from spikegyro.stream.writer import PredictionWriter, read_predictions, write_predictions


@pytest.mark.parametrize("suffix", [".csv", ".h5"])
def test_round_trip_with_gyro(tmp_path, suffix):
    t = np.arange(1000, 6000, 1000, dtype=np.int64) + 1_234_567_000
    omega = np.linspace(-3, 3, 15).reshape(5, 3)
    gyro = omega + 0.5
    path = write_predictions(tmp_path / f"pred{suffix}", t, omega, gyro)
    back = read_predictions(path)
    np.testing.assert_array_equal(back["t_us"], t)
    np.testing.assert_allclose(back["omega"], omega, rtol=1e-6)
    np.testing.assert_allclose(back["gyro_omega"], gyro, rtol=1e-6)


def test_csv_error_column_is_the_euclidean_error(tmp_path):
    omega = np.array([[1.0, 2.0, 2.0], [0.0, 0.0, 0.0]])
    gyro = np.array([[1.0, 0.0, 0.0], [3.0, 0.0, 4.0]])
    path = write_predictions(tmp_path / "pred.csv", np.array([1000, 2000]), omega, gyro)
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, -1], [np.sqrt(8.0), 5.0], rtol=1e-6)


def test_csv_reads_back_as_a_gyro_trace(tmp_path):
    omega = np.array([[0.1, -0.2, 0.3], [0.4, 0.5, -0.6]])
    path = write_predictions(tmp_path / "pred.csv", np.array([1000, 2000]), omega)
    trace = read_gyro(path)
    np.testing.assert_array_equal(trace.t, [1000, 2000])
    np.testing.assert_allclose(trace.omega, omega, rtol=1e-6)


def test_appends_in_blocks_and_leaves_nothing_on_failure(tmp_path):
    path = tmp_path / "pred.h5"
    with PredictionWriter(path) as w:
        for k in range(3):
            w.append(np.array([k * 2000, k * 2000 + 1000]), np.full((2, 3), float(k)))
    assert read_predictions(path)["omega"].shape == (6, 3)
    failed = tmp_path / "failed.csv"
    with pytest.raises(RuntimeError), PredictionWriter(failed) as w:
        w.append(np.array([1000]), np.zeros((1, 3)))
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pred.h5"]


def test_rejects_unknown_extension(tmp_path):
    with pytest.raises(InputError, match=r"pred\.json"):
        write_predictions(tmp_path / "pred.json", np.array([0]), np.zeros((1, 3)))
