"""Dataset generator: determinism across workers and Dask, resume, splits, official export, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from spikegyro.cli import app
from spikegyro.errors import InputError
from spikegyro.events.io import OFFICIAL_KEYS, read_recording, write_recording
from spikegyro.sim.camera import Camera
from spikegyro.sim.dataset import (
    SCENE_KINDS,
    SimConfig,
    export_official,
    generate_dataset,
    scene_kind,
    sequence_path,
    simulate_sequence,
    split_counts,
)
from spikegyro.sim.panorama import bundled_panorama_paths, split_panoramas

TINY = SimConfig(duration_ms=200, camera=Camera.scaled(48, 36))


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*.h5"))}


@pytest.fixture(scope="module")
def serial(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("serial")
    generate_dataset(out, 4, seed=5, config=TINY, workers=1)
    return out


def test_same_seed_gives_identical_files_with_process_workers(serial, tmp_path):
    generate_dataset(tmp_path, 4, seed=5, config=TINY, workers=2)
    assert _files(tmp_path) == _files(serial)
    assert (tmp_path / "meta.json").read_bytes() == (serial / "meta.json").read_bytes()


def test_dask_cluster_gives_identical_files(serial, tmp_path):
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2, processes=False, threads_per_worker=1, dashboard_address=None
    ) as cluster:
        generate_dataset(tmp_path, 4, seed=5, config=TINY, scheduler=cluster.scheduler_address)
    assert _files(tmp_path) == _files(serial)


def test_resume_skips_finished_files_and_rejects_other_options(serial, tmp_path):
    generate_dataset(tmp_path, 4, seed=5, config=TINY)
    victim = sequence_path(tmp_path, "train", 1)
    victim.unlink()
    kept = sequence_path(tmp_path, "val", 0)
    stamp = kept.stat().st_mtime_ns
    calls = []
    generate_dataset(tmp_path, 4, seed=5, config=TINY, on_sequence=lambda *a: calls.append(a))
    assert len(calls) == 1 and kept.stat().st_mtime_ns == stamp
    assert _files(tmp_path) == _files(serial)
    with pytest.raises(InputError, match="other options"):
        generate_dataset(tmp_path, 4, seed=6, config=TINY)


def test_meta_and_sequence_files(serial):
    meta = json.loads((serial / "meta.json").read_text())
    assert meta["complete"] and meta["sequences"] == {"train": 2, "val": 1, "test": 1}
    assert SimConfig.from_dict(meta["config"]) == TINY
    stats = meta["statistics"]["events_per_100ms"]
    assert stats["p0"] <= stats["p50"] <= stats["p100"]
    rec = read_recording(sequence_path(serial, "train", 0))
    assert rec.events.width == 48 and rec.attrs["fx"] == pytest.approx(40.0)
    assert rec.attrs["seed"] == 5 and rec.attrs["split"] == "train"
    assert list(rec.gyro.t[[0, -1]]) == [0, 200_000] and len(rec.gyro) == 201
    per_window = [int(((rec.events.t >= a) & (rec.events.t < a + 100_000)).sum()) for a in (0, 1e5)]
    assert rec.attrs["events_per_100ms"] == per_window
    with h5py.File(sequence_path(serial, "train", 0)) as f:
        assert set(OFFICIAL_KEYS) <= set(f)


def test_sequences_depend_on_split_and_index_only():
    a = simulate_sequence(TINY, 3, seed=1, split="val")
    b = simulate_sequence(TINY, 3, seed=1, split="val")
    c = simulate_sequence(TINY, 3, seed=1, split="test")
    np.testing.assert_array_equal(a.events.t, b.events.t)
    assert a.attrs["scene"] == b.attrs["scene"]
    assert a.attrs["r0"] != c.attrs["r0"]


def test_sequences_record_their_scene_kind_which_older_files_derive_from_the_scene(tmp_path):
    # Events and ground truth of the ideal sensor are pinned bit for bit by
    # test_sim_sensor.test_ideal_sensor_reproduces_the_files_made_before_sensor_presets.
    expected = {"ideal": {"photo", "procedural"}, "davis240c": set(SCENE_KINDS)}
    for sensor, kinds in expected.items():
        config = SimConfig(duration_ms=100, camera=Camera.scaled(48, 36), sensor=sensor)
        seen = set()
        for index in range(6):
            rec = simulate_sequence(config, index, seed=3, split="train")
            older = {k: v for k, v in rec.attrs.items() if k != "scene_kind"}
            assert scene_kind(older) == rec.attrs["scene_kind"] == scene_kind(rec.attrs)
            seen.add(rec.attrs["scene_kind"])
        assert seen == kinds, sensor
    path = write_recording(tmp_path / "seq.h5", rec)
    assert read_recording(path).attrs["scene_kind"] == rec.attrs["scene_kind"]
    made_here = {"generator": "spikegyro 0.1.0"}
    assert scene_kind({**made_here, "scene": "forest_slope"}) == "photo"
    assert scene_kind({**made_here, "scene": "sparse/test/4"}) == "sparse"
    assert scene_kind({**made_here, "scene": "other/test/4"}) == "unknown"
    assert scene_kind({"scene": "unit-test"}) == scene_kind({}) == "unknown"


def test_a_scene_mix_chooses_the_kinds_and_leaves_the_sensor_draws_alone():
    base = SimConfig(duration_ms=100, camera=Camera.scaled(48, 36), sensor="davis240c")
    only = {kind: SimConfig(**{**base.__dict__, "scene_mix": tuple(float(k == kind)
                                                                   for k in SCENE_KINDS)})
            for kind in ("sparse", "office")}  # fmt: skip
    for index in range(3):
        default = simulate_sequence(base, index, seed=3, split="train")
        for kind, config in only.items():
            rec = simulate_sequence(config, index, seed=3, split="train")
            assert rec.attrs["scene_kind"] == kind
            # the scene is drawn with the same random numbers: the sensor's draws are unchanged
            assert rec.attrs["contrast_on"] == default.attrs["contrast_on"]
            assert rec.attrs["sensor_calib"] == default.attrs["sensor_calib"]
    assert SimConfig.from_dict(only["office"].to_dict()) == only["office"]
    with pytest.raises(InputError, match="needs a sensor preset"):
        SimConfig(scene_mix=(1, 0, 0, 0))
    with pytest.raises(InputError, match="4 weights"):
        SimConfig(sensor="davis240c", scene_mix=(1, 0, 0))
    with pytest.raises(InputError, match="not all 0"):
        SimConfig(sensor="davis240c", scene_mix=(0, 0, 0, 0))


def test_splits_are_disjoint_by_panorama(tmp_path):
    bundled = split_panoramas(bundled_panorama_paths())
    assert [len(bundled[s]) for s in ("train", "val", "test")] == [10, 1, 1]
    for i in range(30):
        Image.fromarray(np.full((8, 16), i * 8, np.uint8)).save(tmp_path / f"p{i:02d}.png")
    folder = split_panoramas(sorted(tmp_path.glob("*.png")))
    names = [{p.name for p in folder[s]} for s in ("train", "val", "test")]
    assert sum(map(len, names)) == 30 and not (names[0] & names[1] or names[0] & names[2])
    assert split_counts(10_000) == {"train": 9000, "val": 500, "test": 500}
    # Sequences of a split draw only that split's photographs.
    cfg = SimConfig(duration_ms=100, camera=Camera.scaled(32, 24), procedural_fraction=0.0)
    scenes = {simulate_sequence(cfg, i, 0, "test").attrs["scene"] for i in range(3)}
    assert scenes == {f"{bundled['test'][0].stem}+detail"}


def test_official_export_round_trips(serial, tmp_path):
    written = export_official(serial, tmp_path)
    assert written == {"train": 4, "val": 2, "test": 2}  # 200 ms -> 2 samples each
    src = read_recording(sequence_path(serial, "train", 1))
    path = tmp_path / "train" / "0000003.h5"  # sequence 1, window 1
    with h5py.File(path) as f:
        assert set(OFFICIAL_KEYS) <= set(f)
        ang_ts, ang_xyz = f["ang_ts"][()], f["ang_xyz"][()]
        ev_ts, ev_xy, ev_pol = f["ev_ts"][()], f["ev_xy"][()], f["ev_pol"][()]
    # What the official loader computes: one bin per gyro sample, 1 ms apart.
    np.testing.assert_array_equal(ang_ts, np.arange(1, 101) * 1000)
    assert ang_xyz.shape == (100, 3) and ev_xy.shape == (len(ev_ts), 2)
    assert ev_ts.min() >= 0 and ev_ts.max() < 100_000
    window = src.events.slice_time(100_000, 200_000)
    np.testing.assert_array_equal(ev_ts, window.t - 100_000)
    np.testing.assert_array_equal(ev_xy[:, 0], window.x)
    np.testing.assert_array_equal(ev_pol, window.p)
    np.testing.assert_allclose(ang_xyz, src.gyro.omega[101:201])
    back = read_recording(path)
    np.testing.assert_array_equal(back.events.y, window.y)


def test_cli_simulate_export_show(tmp_path):
    runner = CliRunner()
    out = tmp_path / "ds"
    args = ["simulate", "--out", str(out), "--sequences", "1", "--duration-ms", "100"]
    res = runner.invoke(app, [*args, "--width", "32", "--height", "24", "--compression", "gzip"])
    assert res.exit_code == 0, res.output
    with h5py.File(sequence_path(out, "train", 0)) as f:
        assert f["ev_ts"].compression == "gzip" and f.attrs["width"] == 32
    res = runner.invoke(app, [*args, "--compression", "zip"])
    assert isinstance(res.exception, InputError) and "compression" in str(res.exception)
    res = runner.invoke(app, ["export-official", str(out), str(tmp_path / "off")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "off" / "train" / "0000000.h5").exists()
    fig = tmp_path / "fig.png"
    res = runner.invoke(app, ["show", str(sequence_path(out, "train", 0)), "--out", str(fig)])
    assert res.exit_code == 0, res.output
    with Image.open(fig) as im:
        assert im.size[0] > 500 and im.size[1] > 500


def test_cli_slow_share_makes_every_sequence_slow_and_is_recorded(tmp_path):
    out = tmp_path / "slow"
    args = ["simulate", "--out", str(out), "--sequences", "4", "--duration-ms", "100"]
    size = ["--width", "32", "--height", "24"]
    res = CliRunner().invoke(app, [*args, *size, "--slow-share", "1", "--slow-speed", "5", "40"])
    assert res.exit_code == 0, res.output
    meta = json.loads((out / "meta.json").read_text())
    assert meta["config"]["trajectory"]["slow_share"] == 1.0
    for split, index in [("train", 0), ("val", 0), ("test", 0)]:
        path = sequence_path(out, split, index)
        if path.exists():
            speed = np.degrees(np.linalg.norm(read_recording(path).gyro.omega, axis=1))
            # 5-40 deg/s at the start; the drift (0.5 x speed per s) stays within 10 % in 0.1 s
            assert speed.min() > 4.0 and speed.max() < 45.0
    res = CliRunner().invoke(app, [*args, *size, "--slow-speed", "40", "5"])
    assert isinstance(res.exception, InputError) and "--slow-speed" in str(res.exception)


def test_cli_simulates_a_flip_and_rejects_bad_flips(tmp_path):
    out = tmp_path / "flip"
    args = ["simulate", "--out", str(out), "--sequences", "1", "--width", "32", "--height", "32"]
    flip = ["--trajectory", "flip", "--duration-ms", "300", "--flip-ms", "200"]
    res = CliRunner().invoke(app, [*args, *flip, "--flip-deg", "180"])
    assert res.exit_code == 0, res.output
    meta = json.loads((out / "meta.json").read_text())
    assert meta["config"]["trajectory"]["kind"] == "flip"
    gyro = read_recording(sequence_path(out, "train", 0)).gyro
    roll = np.degrees(np.trapezoid(gyro.omega[:, 2], gyro.t / 1e6))
    assert abs(roll - 180.0) < 0.5  # 1 kHz samples of a 180 deg flip in 200 ms
    assert abs(np.degrees(gyro.omega[:, 2]).max() - 1800.0) < 1.0
    for bad, option in [
        (["--trajectory", "loop"], "--trajectory"),
        ([*flip, "--flip-ms", "400"], "--flip-ms"),
        ([*flip, "--flip-deg", "-90"], "--flip-deg"),
    ]:
        res = CliRunner().invoke(app, [*args[:2], str(tmp_path / "bad"), *args[3:], *bad])
        assert isinstance(res.exception, InputError) and option in str(res.exception), bad
        assert not (tmp_path / "bad" / "meta.json").exists()
