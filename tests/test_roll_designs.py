"""SNN-6 variants for roll and slow motion: log-polar input channels, longer time constants,
and carrying the shipped weights over to them (``train --init``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spikegyro.errors import InputError
from spikegyro.events.representations import (
    log_polar_coordinates,
    log_polar_pixel_map,
    log_polar_spikes,
    spike_tensor,
)
from spikegyro.models.registry import (
    PRETRAINED_SNN6,
    build_model,
    load_checkpoint,
    read_checkpoint,
    save_checkpoint,
)
from spikegyro.models.snn6 import SNN6, SNN6_LAYERS, adapt_state
from spikegyro.snn.kernels import refractory_kernel, srm_kernel

H, W = 90, 120
CENTRE = (60.0, 45.0)


def _cell_centres(cols: np.ndarray, rows: np.ndarray, r_min: float) -> tuple[np.ndarray, ...]:
    """Image points at the middle of log-polar cells, from the closed-form inverse map."""
    r_max = max(math.hypot(a - CENTRE[0], b - CENTRE[1]) for a in (0, W - 1) for b in (0, H - 1))
    radius = r_min * np.exp((rows + 0.5) / H * np.log(r_max / r_min))
    angle = (cols + 0.5) * 2 * np.pi / W
    return CENTRE[0] + radius * np.cos(angle), CENTRE[1] + radius * np.sin(angle), radius


def test_roll_is_a_shift_along_the_angle_axis() -> None:
    rng = np.random.default_rng(0)
    cols, rows = rng.integers(0, W, 500), rng.integers(0, H, 500)
    x, y, _ = _cell_centres(cols, rows, r_min=2.0)
    col, row, keep = log_polar_coordinates(x, y, height=H, width=W, centre=CENTRE)
    assert keep.all() and (col == cols).all() and (row == rows).all()
    for k in (1, 7, 30, 119):  # a roll by k columns' worth of angle, about the centre
        phi = 2 * np.pi * k / W
        dx, dy = x - CENTRE[0], y - CENTRE[1]
        xr = CENTRE[0] + dx * np.cos(phi) - dy * np.sin(phi)
        yr = CENTRE[1] + dx * np.sin(phi) + dy * np.cos(phi)
        col_r, row_r, _ = log_polar_coordinates(xr, yr, height=H, width=W, centre=CENTRE)
        assert (row_r == row).all()
        assert (col_r == (col + k) % W).all()


def test_radius_maps_to_log_rows() -> None:
    r_min = 2.0
    r_max = math.hypot(60.0, 45.0)  # farthest corner (0, 0) from (60, 45)
    radius = np.array([2.0, 2.5, 5.0, 10.0, 20.0, 40.0, 70.0])
    x, y = CENTRE[0] + radius, np.full_like(radius, CENTRE[1])  # along +x: angle 0, column 0
    col, row, keep = log_polar_coordinates(x, y, height=H, width=W, centre=CENTRE, r_min=r_min)
    expected = np.minimum(np.floor(H * np.log(radius / r_min) / np.log(r_max / r_min)), H - 1)
    assert keep.all() and (col == 0).all() and (row == expected).all()
    # Doubling the radius moves by the same number of rows anywhere: a scaling is a shift too.
    rows_per_octave = H * np.log(2) / np.log(r_max / r_min)
    assert np.diff(row[2:6]).tolist() == [pytest.approx(rows_per_octave, abs=1)] * 3
    # Straight down the image (y grows) is a quarter turn: column W/4.
    col_d, _, _ = log_polar_coordinates(
        np.array([60.0]), np.array([80.0]), height=H, width=W, centre=CENTRE
    )
    assert col_d.tolist() == [W // 4]
    _, _, inner = log_polar_coordinates(
        np.array([60.5, 61.0]), np.array([45.0, 47.0]), height=H, width=W, centre=CENTRE
    )
    assert inner.tolist() == [False, True]
    with pytest.raises(InputError):
        log_polar_coordinates(x, y, height=H, width=W, centre=CENTRE, r_min=0.0)


def test_dense_remap_equals_binning_the_mapped_events() -> None:
    rng = np.random.default_rng(1)
    n = 4000
    x, y = rng.integers(0, W, n), rng.integers(0, H, n)
    t, p = np.sort(rng.integers(0, 20_000, n)), rng.integers(0, 2, n)
    dense = spike_tensor(x, y, t, p, height=H, width=W, t_start_us=0, num_bins=20)
    remapped = log_polar_spikes(
        torch.from_numpy(dense), log_polar_pixel_map(H, W, CENTRE), spatial_dim=1
    )
    col, row, keep = log_polar_coordinates(x, y, height=H, width=W, centre=CENTRE)
    direct = spike_tensor(
        col[keep], row[keep], t[keep], p[keep], height=H, width=W, t_start_us=0, num_bins=20
    )
    assert torch.equal(remapped, torch.from_numpy(direct))


def _shipped() -> SNN6:
    model, _ = load_checkpoint(PRETRAINED_SNN6)
    return model.double()


def _input(seed: int = 0, steps: int = 40) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(1, 2, H, W, steps, generator=g, dtype=torch.float64) < 0.03).double()


def test_log_polar_network_with_zero_weights_is_the_shipped_network() -> None:
    shipped = _shipped()
    lp = build_model("snn6", log_polar=True).double().eval()
    assert lp.conv1.weight.shape[1] == 4
    lp.load_state_dict(adapt_state(shipped.state_dict(), lp))
    x = _input()
    with torch.no_grad():
        ref = shipped(x)
        out = lp(x)
    assert ref.abs().max() > 0
    assert torch.equal(out, ref)
    # The extra channels are the log-polar copy of the input, in time-major storage.
    full = lp.with_log_polar(x)
    assert full.shape == (1, 4, H, W, 40) and torch.equal(full[:, :2], x)
    assert full.permute(4, 0, 1, 2, 3).is_contiguous()
    assert 0 < full[:, 2:].sum() <= x.sum()


def test_tau_scaled_kernels_and_weight_carry_over() -> None:
    model = build_model("snn6", tau_scale=2.0, readout_tau=24.0)
    for conv, spec in zip(model.convs, SNN6_LAYERS, strict=True):
        assert conv.params.tau_s == 2 * spec.params.tau_s
        assert conv.params.tau_r == 2 * spec.params.tau_r
        torch.testing.assert_close(conv.srm_kernel, srm_kernel(2 * spec.params.tau_s))
        torch.testing.assert_close(
            conv.ref_kernel, refractory_kernel(spec.params.theta, 2 * spec.params.tau_r)
        )
    torch.testing.assert_close(model.fc.srm_kernel, srm_kernel(24.0))
    shipped = read_checkpoint(PRETRAINED_SNN6)["state_dict"]
    state = adapt_state(shipped, model)
    model.load_state_dict(state)  # the model keeps its own (longer) kernels
    area = lambda k: float(k.double().sum())  # noqa: E731
    ratio = area(shipped["fc.srm_kernel"]) / area(srm_kernel(24.0))
    assert 0.3 < ratio < 0.36  # ε's area grows with τ (e·τ for long kernels)
    torch.testing.assert_close(model.fc.weight, shipped["fc.weight"] * ratio)
    torch.testing.assert_close(state["conv1.srm_kernel"], srm_kernel(4.0))
    with pytest.raises(InputError):
        build_model("snn6", tau_scale=0.0)


def test_checkpoints_round_trip_with_the_new_options(tmp_path) -> None:
    kwargs = {"log_polar": True, "tau_scale": 1.5, "readout_tau": 16.0, "grid": [2, 2]}
    torch.manual_seed(0)
    model = build_model("snn6-grid", **kwargs).eval()
    path = save_checkpoint(
        tmp_path / "m.pt", model, name="snn6-grid", model_kwargs=kwargs,
        input_spec={"representation": "spikes", "sensor": [240, 180], "scale": 0.5},
    )  # fmt: skip
    loaded, payload = load_checkpoint(path)
    assert payload["model_kwargs"] == kwargs
    assert loaded.log_polar and loaded.readout_grid == (2, 2)
    x = _input(steps=30).float()
    with torch.no_grad():
        assert torch.equal(loaded(x), model(x))


@pytest.mark.parametrize("kwargs", [{"log_polar": True}, {"tau_scale": 2.0, "readout_tau": 24.0}])
def test_event_engine_takes_the_variants(kwargs: dict) -> None:
    """The event-driven CPU engine (``train --compute sparse``) reads each layer's kernels and
    input channels from the layers themselves: same output as the batch path."""
    torch.manual_seed(0)
    model = build_model("snn6", **kwargs).eval()
    model.set_surrogate_cut(0.05)
    x = (torch.rand(2, 2, 63, 63, 25) < 0.05).float()
    with torch.no_grad():
        reference = model(x)
        model.use_event_engine(2)
        assert torch.equal(model(x), reference)


def test_stream_engine_hands_the_variants_to_the_batched_path(tmp_path, capsys) -> None:
    from spikegyro.stream.engine import load_engine
    from spikegyro.stream.model import BatchedOnly, load_streaming_model
    from spikegyro.stream.stateful import StreamingSNN

    spec = {"representation": "spikes", "sensor": [240, 180], "scale": 0.5, "window_ms": 100}
    for name, kwargs in (("snn6", {"log_polar": True}), ("snn6-grid", {"grid": [2, 2]})):
        path = save_checkpoint(
            tmp_path / f"{name}.pt", build_model(name, **kwargs), name=name,
            model_kwargs=kwargs, input_spec=spec,
        )  # fmt: skip
        with pytest.raises(BatchedOnly):
            load_streaming_model(path)
        engine, meta = load_engine(path)
        assert callable(engine) and not isinstance(engine, StreamingSNN)
        assert meta["model_kwargs"] == kwargs
        assert "batched path" in capsys.readouterr().err
    plain = save_checkpoint(
        tmp_path / "plain.pt",
        build_model("snn6", tau_scale=2.0),
        name="snn6",
        model_kwargs={"tau_scale": 2.0},
        input_spec=spec,
    )
    assert isinstance(load_engine(plain)[0], StreamingSNN)  # longer taus stream exactly


def test_log_polar_share_splits_conv1_between_the_two_grids() -> None:
    shipped = read_checkpoint(PRETRAINED_SNN6)["state_dict"]
    lp = build_model("snn6", log_polar=True, log_polar_share=0.25)
    state = adapt_state(shipped, lp)
    cart, polar = state["conv1.weight"][:, :2], state["conv1.weight"][:, 2:]
    torch.testing.assert_close(cart, 0.75 * shipped["conv1.weight"])
    torch.testing.assert_close(polar, 0.25 * shipped["conv1.weight"])
    # An input seen identically on both grids drives conv1 exactly as the source network.
    torch.testing.assert_close(cart + polar, shipped["conv1.weight"])
    with pytest.raises(InputError):
        build_model("snn6", log_polar=True, log_polar_share=1.5)
