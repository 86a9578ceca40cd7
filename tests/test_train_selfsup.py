"""The self-supervised contrast loss: its gradient through autograd against finite differences,
its minimum at the true ω of simulated windows (the ESIM simulator, an independent event
generator), the teacher's estimates, which sub-windows carry a loss, and real recordings'
checks."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spikegyro.cmax.config import CMaxConfig
from spikegyro.cmax.search import search
from spikegyro.errors import InputError
from spikegyro.train.data import InputSpec
from spikegyro.train.real import RealWindows, load_recordings
from spikegyro.train.selfsup import (
    ContrastLossConfig,
    SubWindow,
    batch_loss,
    gain_loss,
    scored_sub_window,
    sub_problem,
    teacher_series,
    window_loss,
)

OMEGA = np.radians([-40.0, 70.0, 55.0])  # rad/s, slow enough for a 40 ms span to stay in view
CONFIG = ContrastLossConfig()


@pytest.fixture(scope="module")
def simulated():
    """A 120 ms ESIM recording of a textured panorama seen by a camera turning at OMEGA."""
    import spikegyro.sim as sim
    from spikegyro.sim.procedural import panorama_width, procedural_panorama

    camera = sim.Camera()
    panorama = procedural_panorama(np.random.default_rng(10), panorama_width(camera))
    trajectory = sim.Trajectory.constant(OMEGA, duration_s=0.12)
    rng = np.random.default_rng(4)
    events = sim.simulate(panorama, trajectory, camera, sim.EventSimConfig(), rng).events
    return events, camera


def _sub(simulated, t_ref_us: int = 100_000, step: int = 99) -> SubWindow:
    events, camera = simulated
    problem = sub_problem(events, t_ref_us, camera, CONFIG, np.random.default_rng(0))
    assert problem is not None
    c0 = problem.contrast(np.zeros(3), 1, CONFIG.sigma_px)[0]
    return SubWindow(step, problem, c0, OMEGA.astype(np.float32), 2.0)


def test_loss_is_zero_at_rest_and_lowest_at_the_true_rotation(simulated) -> None:
    sub = _sub(simulated)

    def loss(omega: np.ndarray) -> float:
        return float(gain_loss(torch.tensor(omega, dtype=torch.float64), sub, CONFIG.sigma_px))

    assert loss(np.zeros(3)) == pytest.approx(0.0, abs=1e-12)
    at_truth = loss(OMEGA)
    assert at_truth < -0.5  # the true rotation sharpens the image clearly
    # the minimum, found by contrast maximization's own search, lies near the truth
    best = search(sub.problem, CMaxConfig()).omega
    assert np.linalg.norm(best - OMEGA) < 0.15 * np.linalg.norm(OMEGA), np.degrees(best)
    for axis in range(3):
        for factor in (0.6, 1.4):
            moved = OMEGA.copy()
            moved[axis] *= factor
            assert loss(moved) > at_truth, (axis, factor)
    # flinging the events off the image never pays (no collapse)
    assert loss(10.0 * OMEGA) > at_truth
    assert loss(np.radians([0.0, 0.0, 3000.0])) > at_truth


def test_gradient_through_autograd_matches_finite_differences(simulated) -> None:
    """A linear read-out W (3 x 4) of fixed features gives ω(t); the loss's gradient wrt W, by
    autograd through the bridge, equals central differences of the loss itself."""
    sub = _sub(simulated, t_ref_us=80_000, step=79)
    features = torch.tensor(np.random.default_rng(1).normal(size=(4, 100)), dtype=torch.float64)
    weights = torch.tensor(np.random.default_rng(2).normal(0, 0.3, (3, 4)), dtype=torch.float64)
    weights[:, 0] += torch.tensor(OMEGA) / features[0, 79]  # near the peak, where it matters

    def loss(w: torch.Tensor) -> torch.Tensor:
        return batch_loss((w @ features)[None], [[sub]], CONFIG, "contrast")

    w = weights.clone().requires_grad_(True)
    loss(w).backward()
    eps = 1e-6
    numeric = torch.zeros_like(weights)
    for i in range(3):
        for j in range(4):
            step = torch.zeros_like(weights)
            step[i, j] = eps
            numeric[i, j] = (loss(weights + step) - loss(weights - step)) / (2 * eps)
    scale = numeric.abs().max()
    np.testing.assert_allclose(w.grad.numpy(), numeric.numpy(), atol=2e-3 * float(scale))


def test_descending_the_loss_from_a_wrong_start_finds_the_rotation(simulated) -> None:
    sub = _sub(simulated)
    omega = torch.tensor(0.6 * OMEGA, requires_grad=True)
    optimizer = torch.optim.Adam([omega], lr=0.02)
    for _ in range(150):
        optimizer.zero_grad()
        gain_loss(omega, sub, CONFIG.sigma_px).backward()
        optimizer.step()
    error = np.linalg.norm(omega.detach().numpy() - OMEGA)
    assert error < 0.15 * np.linalg.norm(OMEGA), np.degrees(omega.detach().numpy())


def test_teacher_series_recovers_the_rotation(simulated) -> None:
    events, camera = simulated
    series = teacher_series(events, camera, CONFIG, 10_000)
    assert series.t_us[0] == int(events.t[0]) + 40_000
    found = np.isfinite(series.gain)
    assert found.sum() >= len(series.t_us) - 1
    for omega, gain in zip(series.omega[found], series.gain[found], strict=True):
        assert np.linalg.norm(omega - OMEGA) < 0.15 * np.linalg.norm(OMEGA)
        assert gain > 1.2
    sub = scored_sub_window(events, int(series.t_us[3]), 99, camera, series, CONFIG)
    assert sub is not None and sub.teacher_gain == pytest.approx(series.gain[3])


def test_window_loss_skips_what_one_rotation_does_not_explain(simulated) -> None:
    sub = _sub(simulated)
    weak = SubWindow(sub.step, sub.problem, sub.c0, sub.teacher, CONFIG.min_gain - 0.01)
    omega = torch.zeros(3, 100, dtype=torch.float64)
    assert window_loss(omega, [weak], CONFIG, "contrast") is None
    assert window_loss(omega, [weak, sub], CONFIG, "contrast") == pytest.approx(0.0, abs=1e-12)
    # the teacher variant: the Euclidean distance to the teacher's estimate, rad/s
    teacher = window_loss(omega, [weak, sub], CONFIG, "teacher")
    assert float(teacher) == pytest.approx(np.linalg.norm(OMEGA), rel=1e-6)
    # a batch whose windows all lack a loss still gives a (zero) loss on the graph
    out = torch.ones(2, 3, 100, requires_grad=True)
    total = batch_loss(out, [[weak], []], CONFIG, "contrast")
    total.backward()
    assert total.item() == 0.0 and out.grad is not None


def _text_recording(path, events, duration_s: float | None = None) -> str:
    t = (events.t - events.t[0]) * 1e-6
    keep = np.ones(len(t), bool) if duration_s is None else t < duration_s
    rows = np.column_stack([t[keep], events.x[keep], events.y[keep], events.p[keep]])
    np.savetxt(path, rows, fmt=["%.6f", "%d", "%d", "%d"])
    return str(path)


def test_real_recordings_are_checked_before_any_work(simulated, tmp_path) -> None:
    events, _ = simulated
    rec = _text_recording(tmp_path / "rec.txt", events)
    with pytest.raises(InputError, match="no calibration"):
        load_recordings([rec], [], 50, 0.4, CONFIG)
    with pytest.raises(InputError, match="neither a calibration file nor"):
        load_recordings([rec], ["200,200,120"], 50, 0.4, CONFIG)
    with pytest.raises(InputError, match="needs at least 100 ms on each side"):
        load_recordings([rec], ["200,200,120,90"], 100, 0.5, CONFIG)
    with pytest.raises(InputError, match="one for all, or one per --real"):
        load_recordings([rec, rec, rec], ["a", "b"], 50, 0.4, CONFIG)
    sparse = tmp_path / "sparse.txt"
    sparse.write_text("0.0 1 1 1\n0.5 2 2 0\n1.0 3 3 1\n")
    with pytest.raises(InputError, match="too few to learn from"):
        load_recordings([str(sparse)], ["200,200,120,90"], 50, 0.4, CONFIG)


def test_real_windows_draw_reproducibly_and_hold_out_the_end(simulated, tmp_path) -> None:
    events, _ = simulated
    rec = _text_recording(tmp_path / "rec.txt", events)
    config = ContrastLossConfig(from_step=30, span_ms=30.0)
    recordings = load_recordings([rec], ["200,200,120,90"], 40, 0.5, config, progress=False)
    windows = RealWindows(recordings, InputSpec(window_ms=40), config, seed=3)
    first, again = windows.draw(7, 4), windows.draw(7, 4)
    assert [w.t_start_us for w, _ in first] == [w.t_start_us for w, _ in again]
    train_end = recordings[0].train_span[1] + 40_000
    for window, subs in first:
        assert window.t_end_us <= train_end and np.isnan(window.omega).all()
        assert [s.step for s in subs] == [39] and subs[0].teacher_gain > 1.2
    held_out = windows.validation()
    assert held_out and all(w.t_start_us >= train_end for w, _ in held_out)


def test_adapt_trains_on_a_real_recording_and_writes_the_best_weights(simulated, tmp_path):
    """`adapt` end to end on a recording without a gyro (the simulator's, as a text file): a
    step-0 row with the starting weights' gain, training steps with a finite loss, validations,
    and a checkpoint that loads."""
    import csv

    from spikegyro.models.registry import read_checkpoint
    from spikegyro.train.adapt import AdaptSettings, adapt, adapt_config, run_dir_of

    events, _ = simulated
    rec = _text_recording(tmp_path / "rec.txt", events)
    out = tmp_path / "cam.pt"
    settings = AdaptSettings([rec], "200,200,120,90", "snn6", out, max_minutes=5, batch_size=2)
    config = adapt_config(settings)
    short = {
        "window_ms": 50,
        "train_window_ms": 50,
        "loss_start_step": 30,
        "train_loss_start_step": 30,
        "real_holdout": 0.5,
    }  # a 118 ms recording
    config = type(config)(**{**config.as_dict(), "sensor": (240, 180), "iterations": 4,
                             "val_every": 2, "log_every": 1, **short})  # fmt: skip
    adapted = adapt(settings, config)
    rows = list(csv.DictReader((run_dir_of(out) / "log.csv").open()))
    assert rows[0]["step"] == "0" and float(rows[0]["val_real_gain"]) > 0
    assert [r["step"] for r in rows if r["val_real_gain"]] == ["0", "2", "4"]
    assert all(np.isfinite(float(r["loss"])) for r in rows[1:])
    # Real windows only: the whole loss is the real windows' part.
    assert all(float(r["real_loss"]) == pytest.approx(float(r["loss"]), rel=1e-4) for r in rows[1:])
    assert adapted.result.steps == 4
    assert adapted.gain_end >= adapted.gain_start
    assert read_checkpoint(out)["model"] == "snn6"


def test_real_windows_on_the_event_clock_score_each_step_where_it_ends(simulated, tmp_path):
    """On the event clock a real window holds whole steps, each scored sub-window ends where
    its step does and carries the factor to rad/s: the true ω, read back through that factor
    from the network's units, sharpens the events as it does on the paper's clock."""
    from spikegyro.events.clock import Clock

    events, _ = simulated
    rec = _text_recording(tmp_path / "rec.txt", events)
    config = ContrastLossConfig(from_step=15, span_ms=30.0)
    recordings = load_recordings([rec], ["200,200,120,90"], 40, 0.5, config, progress=False)
    clock = Clock(len(events) // 200, 200, 10_000)  # steps of about 0.6 ms
    spec = InputSpec(window_ms=20, clock=clock.as_dict())
    windows = RealWindows(recordings, spec, config, seed=3)
    train_end = recordings[0].train_span[1] + 20_000
    for window, subs in windows.draw(5, 3):
        assert window.num_steps == 20 and np.isnan(window.omega).all()
        ends = window.t_start_us + np.cumsum(window.step_us)
        assert ends[-1] <= train_end and window.events.t.max() < 20_000  # the network's time
        assert [s.step for s in subs] == [19]
        sub = subs[0]
        assert sub.rate == pytest.approx(np.full(3, 1000.0 / window.step_us[19]))
        # the network's units: rotation per virtual ms; the true ω there is OMEGA / rate
        truth = torch.from_numpy(np.tile(OMEGA / sub.rate, (20, 1)).T.copy())
        assert float(window_loss(truth, subs, config, "contrast")) < -0.2
        assert float(window_loss(truth * 0, subs, config, "contrast")) == pytest.approx(0.0)


def test_adapt_keeps_the_checkpoints_clock(tmp_path):
    from spikegyro.events.clock import Clock
    from spikegyro.models.registry import save_checkpoint
    from spikegyro.models.snn6 import SNN6
    from spikegyro.train.adapt import CLOCKED_WINDOWS, AdaptSettings, adapt_config

    clock = Clock(800, 1000, 25_000)
    spec = {**InputSpec().as_dict(), "clock": clock.as_dict()}
    ckpt = save_checkpoint(tmp_path / "clocked.pt", SNN6(), name="snn6", model_kwargs={},
                           input_spec=spec)  # fmt: skip
    rec = tmp_path / "rec.txt"
    rec.write_text("0.0 1 1 1\n")
    config = adapt_config(AdaptSettings([str(rec)], "200,200,120,90", str(ckpt),
                                        tmp_path / "out.pt"))  # fmt: skip
    assert Clock.parse(config.clock) == clock and config.real_holdout >= 0.3
    assert all(getattr(config, k) == v for k, v in CLOCKED_WINDOWS.items())
    paper = adapt_config(AdaptSettings([str(rec)], None, "snn6", tmp_path / "out2.pt"))
    assert Clock.parse(paper.clock).is_paper and paper.window_ms == 100
