"""`evaluate` and `report` end to end on a tiny dataset and a randomly initialised checkpoint."""

from __future__ import annotations

import json
import re
import shutil
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

import spikegyro.models  # noqa: F401  (registers the models)
from spikegyro.cli import app, main
from spikegyro.errors import InputError
from spikegyro.evaluate import compare_runs, run_evaluation
from spikegyro.events.core import EventArray, GyroTrace, Recording
from spikegyro.events.io import write_recording
from spikegyro.models.registry import build_model, save_checkpoint
from spikegyro.train.loss import validation_metrics

SENSOR = (64, 64)


def _sequence(
    path: Path, rng: np.random.Generator, duration_ms: int, num_events: int, **attrs: str
):
    """Random events and a slowly varying rotation of a few 100 deg/s."""
    t = np.sort(rng.integers(0, duration_ms * 1000, num_events))
    events = EventArray.from_arrays(
        rng.integers(0, SENSOR[0], t.size), rng.integers(0, SENSOR[1], t.size), t,
        rng.integers(0, 2, t.size), *SENSOR,
    )  # fmt: skip
    gyro_t = np.arange(0, duration_ms * 1000 + 1, 1000)
    omega = np.radians(rng.normal(0, 150, 3)) + np.radians(30) * np.sin(gyro_t / 4e4)[:, None]
    write_recording(path, Recording(events, GyroTrace.from_arrays(gyro_t, omega), attrs))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("data")
    rng = np.random.default_rng(7)
    for i in range(2):
        _sequence(root / "train" / f"seq_{i:06d}.h5", rng, 200, 2000)
    # Three 100 ms test windows, two of them of a sparse scene; the last holds no events.
    _sequence(root / "test" / "seq_000000.h5", rng, 200, 2000, scene_kind="sparse")
    _sequence(root / "test" / "seq_000001.h5", rng, 100, 0)
    return root


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("ckpt") / "snn6.pt"
    model = build_model("snn6")
    spec = {"representation": "spikes", "sensor": list(SENSOR), "scale": 1.0, "window_ms": 100,
            "output": "per_step"}  # fmt: skip
    save_checkpoint(path, model, name="snn6", model_kwargs={}, input_spec=spec)
    return path


@pytest.fixture(scope="module")
def evaluated(dataset, checkpoint, tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("eval")
    result = run_evaluation(dataset, checkpoint, "test", out, num_examples=2, spike_windows=1)
    return out, result


def test_outputs_and_report_hold_every_figure_and_table(evaluated):
    out, result = evaluated
    assert result["model"]["name"] == "SNN-6"
    for name in ("metrics.json", "predictions.npz", "bins.png", "axes.png", "report.md"):
        assert (out / name).exists(), name
    examples = sorted(p.name for p in out.glob("window_*.png"))
    assert examples == ["window_00000.png", "window_00001.png"]  # window 2 has no events
    page = (out / "report.html").read_text()
    # Every PNG is embedded, none is linked (the page is self-contained).
    assert page.count("data:image/png;base64,") == 2 + len(examples)
    assert not re.search(r'src="(?!data:)', page)
    assert page.count("<table>") == 5  # overall, per axis, per bin, per scene kind, spikes
    for text in ("SNN-6", "Mean", "0.26", "66.3", "paper", "[500, inf)"):
        assert text in page, text
    md = (out / "report.md").read_text()
    for name in ["bins.png", "axes.png", *examples]:
        assert f"]({name})" in md


def test_mean_predictor_is_the_training_mean_and_scored_beside_the_model(evaluated, dataset):
    _, result = evaluated
    samples = []
    for path in sorted((dataset / "train").glob("*.h5")):
        with h5py.File(path) as f:
            samples.append(f["ang_xyz"][:])
    expected = np.concatenate(samples).mean(axis=0)
    np.testing.assert_allclose(result["mean"]["omega_rad_s"], expected)
    gt = np.load(Path(evaluated[0]) / "predictions.npz")["gt"][:, 50:]
    err = np.degrees(np.linalg.norm(gt - expected, axis=-1))
    assert result["mean"]["metrics"]["mean_euclidean_error_deg_s"] == pytest.approx(err.mean())


def test_training_validation_scores_the_saved_predictions_as_evaluate_did(evaluated):
    out, result = evaluated
    saved = np.load(out / "predictions.npz")
    val = validation_metrics(saved["pred"], saved["gt"], result["data"]["eval_from_step"])
    m = result["model"]["metrics"]
    assert val["val_median_rel"] == m["median_relative_error"]
    assert val["val_mean_err_deg"] == m["mean_euclidean_error_deg_s"]


def test_metrics_per_scene_kind(evaluated):
    out, result = evaluated
    npz = np.load(out / "predictions.npz")
    for key in ("model", "mean"):
        kinds = result[key]["per_scene_kind"]
        assert list(kinds) == ["sparse", "unknown"]
        assert [kinds[k]["n_windows"] for k in kinds] == [2, 1]
        pred = (
            npz["pred"] if key == "model" else np.broadcast_to(npz["mean_omega"], npz["gt"].shape)
        )
        err = np.degrees(np.abs(pred[2, 50:] - npz["gt"][2, 50:])).mean(axis=0)
        assert list(kinds["unknown"]["mean_abs_error_deg_s"].values()) == pytest.approx(err)
    assert "Per scene kind" in (out / "report.md").read_text()


def test_window_without_events_and_empty_bins_are_reported(evaluated):
    _, result = evaluated
    assert result["data"]["windows"] == 3
    assert result["data"]["windows_without_events"] == 1
    text = " ".join(result["warnings"])
    assert "1 of 3 windows hold no events" in text
    assert "[500, inf)" in text  # no step that fast in this data
    assert result["model"]["spikes"]["windows"] == 1
    rates = [layer["rate_hz"] for layer in result["model"]["spikes"]["layers"][:-1]]
    assert len(rates) == 5 and all(r >= 0 for r in rates)


def test_evaluating_twice_gives_identical_metrics(evaluated, dataset, checkpoint, tmp_path):
    out, _ = evaluated
    run_evaluation(dataset, checkpoint, "test", tmp_path, num_examples=0, spike_windows=1)
    assert (tmp_path / "metrics.json").read_bytes() == (out / "metrics.json").read_bytes()


def test_checkpoint_of_another_resolution_is_refused(dataset, tmp_path):
    path = tmp_path / "wrong.pt"
    spec = {"representation": "spikes", "sensor": [96, 72], "scale": 1.0, "window_ms": 100}
    save_checkpoint(path, build_model("snn6"), name="snn6", model_kwargs={}, input_spec=spec)
    with pytest.raises(InputError, match="trained on 96x72 events"):
        run_evaluation(dataset, path, "test", tmp_path / "out")


def test_bad_arguments_are_refused(dataset, checkpoint, tmp_path):
    with pytest.raises(InputError, match="not both"):
        run_evaluation(dataset, checkpoint, "test", tmp_path, model="cmax")
    with pytest.raises(InputError, match="no such checkpoint"):
        run_evaluation(dataset, tmp_path / "missing.pt", "test", tmp_path)
    with pytest.raises(InputError, match="split"):
        run_evaluation(dataset, checkpoint, "nope", tmp_path)
    with pytest.raises(InputError, match="only 3 windows"):
        run_evaluation(dataset, checkpoint, "test", tmp_path, examples=[3])
    assert not (tmp_path / "metrics.json").exists()  # refused before any work


def test_report_compares_runs_beside_the_paper(evaluated, tmp_path):
    out, result = evaluated
    models = compare_runs([out, out], tmp_path)
    assert list(models) == ["SNN-6", f"SNN-6 [{out.name}]", "Mean"]
    page = (tmp_path / "report.html").read_text()
    assert page.count("data:image/png;base64,") == 3  # bins, boxes, one window
    assert "226.9" in page and "Table I" in page
    saved = json.loads((tmp_path / "comparison.json").read_text())
    assert saved["SNN-6"]["metrics"] == result["model"]["metrics"]
    with pytest.raises(InputError, match=r"no metrics\.json"):
        compare_runs([tmp_path / "nothing"], tmp_path / "x")


def test_per_window_metrics_compare_20_ms_means_and_are_labeled(evaluated):
    out, result = evaluated
    saved = np.load(out / "predictions.npz")
    for key, pred in (("model", saved["pred"]), ("mean", saved["mean_omega"])):
        pred = np.broadcast_to(pred, saved["gt"].shape)
        errors = [
            np.linalg.norm(pred[:, a:b].mean(axis=1) - saved["gt"][:, a:b].mean(axis=1), axis=-1)
            for a, b in ((60, 80), (80, 100))
        ]
        w = result[key]["window_metrics"]
        assert (w["window_ms"], w["sub_windows_ms"], w["n_windows"]) == (
            20,
            [[60, 80], [80, 100]],
            6,
        )
        assert w["mean_euclidean_error_deg_s"] == pytest.approx(np.degrees(errors).mean())
    saved_json = json.loads((out / "metrics.json").read_text())
    assert saved_json["model"]["window_metrics"] == result["model"]["window_metrics"]
    for page in ((out / "report.md").read_text(), (out / "report.html").read_text()):
        assert "per ms (steps ≥ 50)" in page
        assert "per 20 ms window (mean prediction vs mean truth)" in page
        assert "[60, 80) ms and [80, 100) ms" in page


def test_report_finds_the_paper_row_from_the_checkpoint_not_the_name(evaluated, tmp_path):
    out, _ = evaluated
    runs = []
    for name, arch, rep in (("ResNet-50 (V)", "resnet50", "voxel"), ("mine", "resnet50", "frames"),
                            ("ANN-6 (V)", "ann6", "voxel")):  # fmt: skip
        data = json.loads((out / "metrics.json").read_text())
        data["model"].update(name=name, checkpoint_model=arch)
        data["model"]["input"]["representation"] = rep
        run = tmp_path / arch / rep
        run.mkdir(parents=True)
        (run / "metrics.json").write_text(json.dumps(data))
        runs.append(run)
    compare_runs(runs, tmp_path / "cmp")
    saved = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
    rows = {k: v["paper_row"] for k, v in saved.items()}
    assert rows == {"ResNet-50 (V)": "ResNet-50 (voxel)", "mine": "ResNet-50 (accumulated frames)",
                    "ANN-6 (V)": "ANN-6 (voxel)", "Mean": "Mean"}  # fmt: skip
    assert saved["mine"]["window_metrics"]["sub_windows_ms"] == [[60, 80], [80, 100]]
    md = (tmp_path / "cmp" / "report.md").read_text()
    for numbers in ("| 0.15 | 36.8 |", "| 0.22 | 66.8 |", "| 0.22 | 59.0 |", "| 1.00 | 226.9 |"):
        assert numbers in md, numbers


def test_official_checkpoint_is_recognised_and_checked_against_the_data(dataset, tmp_path):
    model = build_model("snn6")
    state = {f"conv{i}.weight": c.weight.detach()[..., None] for i, c in enumerate(model.convs, 1)}
    state["fc.weight"] = model.fc.weight.detach()[..., None, None, None]
    path = tmp_path / "official.pth"
    torch.save({"model_state_dict": state, "epoch": 1}, path)
    # The paper's network takes 240x180 events; the tiny dataset is 64x64.
    with pytest.raises(InputError, match=r"official.pth: the model was trained on 240x180"):
        run_evaluation(dataset, path, "test", tmp_path / "out")


def test_cmax_is_scored_under_its_name_and_nan_steps_count_as_zero(dataset, tmp_path, monkeypatch):
    calls = []

    def fake_cmax(windows, progress=None):
        calls.append(len(windows))
        pred = np.stack([w.omega for w in windows]).astype(np.float64)
        pred[:, 60:70] = np.nan  # e.g. no estimate yet
        return pred

    def fake_live(windows, progress=None, first_step=0):
        return np.zeros((len(windows), 100, 3))

    monkeypatch.setattr("spikegyro.cmax.offline.predict_windows_offline", fake_cmax)
    monkeypatch.setattr("spikegyro.cmax.series.predict_windows", fake_live)
    result = run_evaluation(dataset, None, "test", tmp_path, model="cmax", num_examples=0)
    assert calls == [3]
    assert result["model"]["name"] == "CMax" and "spikes" not in result["model"]
    # The live engine is reported beside the offline one that the CMax row scores.
    assert result["model"]["live"]["name"] == "CMax (live)"
    assert result["model"]["nonfinite_predictions"] == 3 * 10
    # Perfect except 10 of 50 evaluated steps predicted as 0: those have relative error 1.
    rel = result["model"]["metrics"]
    assert rel["median_relative_error"] == pytest.approx(0.0)
    gt = np.load(tmp_path / "predictions.npz")["gt"]
    expected = np.degrees(np.linalg.norm(gt[:, 60:70], axis=-1)).sum() / (3 * 50)
    assert rel["mean_euclidean_error_deg_s"] == pytest.approx(expected)


def test_cli_report_and_user_errors(evaluated, tmp_path, monkeypatch, capsys):
    out, _ = evaluated
    runner = CliRunner()
    done = runner.invoke(app, ["report", str(out), "--out", str(tmp_path / "cmp")])
    assert done.exit_code == 0, done.output
    assert (tmp_path / "cmp" / "report.html").exists()
    monkeypatch.setattr(sys, "argv", ["spikegyro", "report", str(tmp_path / "none"), "--out", "x"])
    with pytest.raises(SystemExit) as exited:
        main()
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "no metrics.json" in err and len(err.splitlines()) == 1


def test_without_a_training_split_the_mean_predictor_says_zero(dataset, tmp_path, monkeypatch):
    data = tmp_path / "data"
    (data / "test").mkdir(parents=True)
    for path in (dataset / "test").glob("*.h5"):
        (data / "test" / path.name).write_bytes(path.read_bytes())
    for engine in ("offline.predict_windows_offline", "series.predict_windows"):
        monkeypatch.setattr(
            f"spikegyro.cmax.{engine}",
            lambda windows, progress=None, first_step=0: np.zeros((len(windows), 100, 3)),
        )
    result = run_evaluation(data, None, "test", tmp_path / "out", model="cmax", num_examples=0)
    assert result["mean"]["omega_rad_s"] == [0.0, 0.0, 0.0]
    assert any("mean predictor uses omega = 0" in w for w in result["warnings"])
    assert result["mean"]["metrics"] == result["model"]["metrics"]  # both predict zeros


def test_ann_whose_windows_do_not_tile_20_ms_is_flagged(dataset, tmp_path):
    path = tmp_path / "ann6.pt"
    spec = {"representation": "voxel", "sensor": list(SENSOR), "scale": 1.0, "window_ms": 100,
            "output": "window_mean", "num_bins": 5, "target_ms": 25}  # fmt: skip
    kwargs = {"in_channels": 5}
    save_checkpoint(path, build_model("ann6", **kwargs), name="ann6", model_kwargs=kwargs,
                    input_spec=spec)  # fmt: skip
    result = run_evaluation(dataset, path, "test", tmp_path / "out", name="x", limit=1,
                            num_examples=0)  # fmt: skip
    assert any("means over 25 ms" in w for w in result["warnings"])
    pred = np.load(tmp_path / "out" / "predictions.npz")["pred"][0]
    assert (pred[75:] == pred[75]).all() and (pred[50:75] == pred[50]).all()  # held 25 ms
    md = (tmp_path / "out" / "report.md").read_text()
    assert "| x | " in md and "| ANN-6 (voxel) | 0.22 | 59.0 |" in md  # by checkpoint, not name


@pytest.fixture(scope="module")
def evaluated_ann(dataset, tmp_path_factory) -> tuple[Path, dict]:
    """ANN-6 on voxel grids, its checkpoint recording a 123-step, 10-minute CUDA run."""
    root = tmp_path_factory.mktemp("ann")
    spec = {"representation": "voxel", "sensor": list(SENSOR), "scale": 1.0, "window_ms": 100,
            "output": "window_mean", "num_bins": 5, "target_ms": 20}  # fmt: skip
    extra = {"step": 123, "elapsed_s": 600.0, "config": {"device": "cuda"}}
    save_checkpoint(root / "ann6.pt", build_model("ann6", in_channels=5), name="ann6",
                    model_kwargs={"in_channels": 5}, input_spec=spec, extra=extra)  # fmt: skip
    result = run_evaluation(dataset, root / "ann6.pt", "test", root / "eval", num_examples=0)
    return root / "eval", result


def _md_rows(md: str) -> dict[str, list[str]]:
    """Table rows of a report.md by their first cell (first occurrence wins)."""
    rows: dict[str, list[str]] = {}
    for line in md.splitlines():
        if line.startswith("| ") and not line.startswith("| model"):
            cells = [c.strip() for c in line.strip("|").split(" | ")]
            rows.setdefault(cells[0], cells)
    return rows


def test_table_one_holds_the_runs_metrics_paper_rows_budget_and_energy(
    evaluated, evaluated_ann, tmp_path
):
    (snn_dir, snn), (ann_dir, ann) = evaluated, evaluated_ann
    compare_runs([snn_dir, ann_dir], tmp_path)
    rows = _md_rows((tmp_path / "report.md").read_text())
    for name, result in (("SNN-6", snn), ("ANN-6", ann)):
        m, w = result["model"]["metrics"], result["model"]["window_metrics"]
        row = rows[name]
        assert row[4:8] == [f"{m['median_relative_error']:.3f}",
                            f"{m['mean_euclidean_error_deg_s']:.1f}",
                            f"{w['median_relative_error']:.3f}",
                            f"{w['mean_euclidean_error_deg_s']:.1f}"]  # fmt: skip
    mean = snn["mean"]["metrics"]
    assert rows["Mean"][4] == f"{mean['median_relative_error']:.3f}"
    paper = "Gehrig et al. 2020 (paper, their data): "
    assert rows[paper + "SNN-6"][4:6] == ["0.26", "66.3"]
    assert rows[paper + "ANN-6 (voxel)"][4:6] == ["0.22", "59.0"]
    assert rows[paper + "Mean"][4:6] == ["1.00", "226.9"]
    # Budget: from the ANN's checkpoint; the SNN fixture's checkpoint records none.
    assert rows["ANN-6"][1:4] == ["voxel grid, 64x64", "123", "10.0 (cuda)"]
    assert rows["SNN-6"][2:4] == ["n/a", "n/a"]
    # Energy, by hand. ANN-6 at 64x64: maps 31, 15, 7, 3, 1 px square; one pass per 20 ms.
    channels, sides = [5, 16, 32, 64, 128, 256], [31, 15, 7, 3, 1]
    macs = sum(s * s * c_out * c_in * 9 for s, c_in, c_out in
               zip(sides, channels[:-1], channels[1:], strict=True)) + 256 * 3  # fmt: skip
    saved = json.loads((tmp_path / "comparison.json").read_text())
    assert saved["ANN-6"]["operations"]["per_estimate"] == macs
    assert saved["ANN-6"]["energy"]["mac_fp32_45nm_mw"] == pytest.approx(macs * 50 * 4.6e-9)
    assert rows["ANN-6"][8:10] == [f"{macs:.3g} MACs", f"{macs * 4.6e-6:.3g}"]
    synops_per_ms = snn["model"]["spikes"]["synops_per_s"] * 1e-3
    assert saved["SNN-6"]["energy"]["add_fp32_45nm_uj_per_estimate"] == pytest.approx(
        synops_per_ms * 0.9e-6
    )
    assert saved["SNN-6"]["energy"]["synop_loihi_mw"] == pytest.approx(
        snn["model"]["spikes"]["synops_per_s"] * 23.6e-9
    )
    assert saved["Mean"]["operations"] is None
    page = (tmp_path / "report.html").read_text()
    assert "Horowitz" in page and "Davies" in page


def test_report_draws_one_window_of_every_model_from_their_predictions(evaluated, tmp_path):
    from spikegyro.evaluate.compare import window_figure

    out, _ = evaluated
    compare_runs([out, out], tmp_path / "cmp")
    assert all((tmp_path / "cmp" / f).exists() for f in ("bins.png", "boxes.png", "window.png"))
    saved = np.load(out / "predictions.npz")
    speed = np.linalg.norm(saved["gt"][:, 50:], axis=-1).mean(axis=1)
    median = int(np.argsort(speed, kind="stable")[len(speed) // 2])
    fig, caption = window_figure([out, out], ["a", "b"], None)
    assert caption.startswith(f"One test window, all models on the same events (paper Fig. 3): "
                              f"window {median}:")  # fmt: skip
    for i, ax in enumerate(fig.axes[:3]):  # tilt, pan, roll
        lines = {line.get_label(): line.get_ydata() for line in ax.get_lines()}
        assert list(lines) == ["ground truth", "a", "b", "Mean"]
        np.testing.assert_allclose(lines["ground truth"], np.degrees(saved["gt"][median, :, i]))
        np.testing.assert_allclose(lines["b"], np.degrees(saved["pred"][median, :, i]))
        np.testing.assert_allclose(lines["Mean"], np.degrees(saved["mean_omega"][i]))
    with pytest.raises(InputError, match=r"--window 3: the runs scored windows 0\.\.2"):
        window_figure([out], ["a"], 3)
    other = tmp_path / "other"
    shutil.copytree(out, other)
    np.savez(other / "predictions.npz", **{**saved, "t_start_us": saved["t_start_us"] + 1000})
    compare_runs([out, other], tmp_path / "cmp2")  # the tables and the other figures still
    assert "No window figure: " in (tmp_path / "cmp2" / "report.md").read_text()
    assert not (tmp_path / "cmp2" / "window.png").exists()
    with pytest.raises(InputError, match="scored other windows"):
        compare_runs([out, other], tmp_path / "cmp3", window=0)


def test_a_report_made_after_the_checkpoint_has_gone_keeps_its_budget_and_operations(
    evaluated_ann, tmp_path
):
    """A GPU machine's run: scored there, its checkpoint left behind, reported elsewhere."""
    from spikegyro.evaluate.compare import operations, training_info

    ann_dir, _ = evaluated_ann
    with_file = compare_runs([ann_dir], tmp_path / "a")["ANN-6"]
    moved = tmp_path / "moved"
    shutil.copytree(ann_dir, moved)
    metrics = json.loads((moved / "metrics.json").read_text())
    metrics["model"]["source"] = str(tmp_path / "gone.pt")
    (moved / "metrics.json").write_text(json.dumps(metrics))
    without = compare_runs([moved], tmp_path / "b")["ANN-6"]
    assert without["info"] == with_file["info"]
    assert without["info"]["steps"] == 123 and without["info"]["minutes"] == 10.0
    assert without["info"]["device"] == "cuda"
    assert without["operations"] == with_file["operations"] is not None
    assert training_info(None)["steps"] is None and operations(metrics["model"], None) is None
    assert "state_dict" not in json.dumps(metrics["model"]["checkpoint_meta"])


def test_event_clock_evaluation_is_the_stream_that_predict_runs(dataset, checkpoint, tmp_path):
    """`evaluate --clock` runs each sequence as one stream and reads it per real ms: the rows
    `predict`'s estimator gives for the same sequence, zeros before its first step."""
    from spikegyro.events.clock import Clock
    from spikegyro.events.io import read_recording
    from spikegyro.stream.engine import load_engine
    from spikegyro.stream.estimator import Estimates
    from spikegyro.stream.predict import SNNEstimator

    clock = "events:150:1-10"
    result = run_evaluation(dataset, checkpoint, "test", tmp_path, clock=clock, num_examples=0,
                            spike_windows=1)  # fmt: skip
    assert "events per step" in result["model"]["name"]
    saved = np.load(tmp_path / "predictions.npz")
    rec = read_recording(dataset / "test" / "seq_000000.h5")
    engine, payload = load_engine(checkpoint)
    estimator = SNNEstimator(engine, {**payload["input"], "clock": Clock.parse(clock).as_dict()})
    t0 = int(saved["t_start_us"][0])
    estimator.reset(t0)
    rows = Estimates.concatenate([estimator.update(rec.events.slice_time(t0, t0 + 200_000)),
                                  estimator.finish(t0 + 200_000)])  # fmt: skip
    stream = np.zeros((200, 3))
    stream[(rows.t_us - t0) // 1000 - 1] = rows.omega
    assert len(rows) > 150 and np.abs(rows.omega).max() > 0
    np.testing.assert_allclose(saved["pred"][:2].reshape(200, 3), stream, rtol=1e-6, atol=1e-9)
