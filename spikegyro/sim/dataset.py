"""The dataset generator: deterministic sequences, local or Dask-parallel, resumable and atomic.

Layout::

    DIR/meta.json                      configuration, version, per-split counts, statistics
    DIR/{train,val,test}/seq_000123.h5 one sequence each (official layout + attributes)

Every sequence is a pure function of (configuration, seed, split, index): its random generator is
``SeedSequence([seed, split number, index])``, so the files are identical whatever the number of
workers or machines, and adding sequences later leaves the existing ones unchanged.

Scenes are split **by panorama**: the bundled photographs 10 train / 1 val / 1 test (see
:data:`spikegyro.sim.panorama.BUNDLED_SPLITS`), a ``--panoramas`` folder 90/5/5 by default.
A fraction of sequences (``procedural_fraction``) uses a procedural panorama generated from the
sequence's own seed stream, which is distinct for every (split, index), so no procedural scene is
shared across splits. Photographs get fine 1/f detail (``detail_strength``) and every sequence
a uniformly random start orientation, i.e. a random orientation of the panorama. Each file names
its scene (attribute ``scene``) and the scene's kind (``scene_kind``, one of :data:`SCENE_KINDS`;
:func:`scene_kind` derives it for files written before that attribute existed).

Sensor presets (``SimConfig.sensor``, :mod:`spikegyro.sim.sensor`): ``ideal`` is the paper's
simulator and gives exactly the files it always gave; ``davis240c`` draws a real sensor per
sequence (thresholds, mismatch, refractory period, background activity, hot pixels,
photoreceptor bandwidth, lens), mixes in sparse and office scenes (:mod:`spikegyro.sim.indoor`)
and maps the distorted events onto the pinhole camera as ``spikegyro predict --calib`` does. The
drawn values are in each file's ``sensor_*`` attributes and in meta.json's ``sensor_draws``.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, astuple, dataclass, field, replace
from functools import lru_cache
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from spikegyro import __version__
from spikegyro.errors import InputError
from spikegyro.events.calib import PinholeCamera
from spikegyro.events.core import GyroTrace, Recording
from spikegyro.events.io import atomic_path, read_recording, write_recording
from spikegyro.sim.camera import Camera
from spikegyro.sim.esim import simulate
from spikegyro.sim.indoor import office_panorama, sparse_panorama
from spikegyro.sim.panorama import (
    Panorama,
    bundled_panorama_paths,
    list_panoramas,
    load_panorama,
    split_panoramas,
)
from spikegyro.sim.procedural import add_detail, panorama_width, procedural_panorama
from spikegyro.sim.sensor import EventSimConfig, SensorParams, SensorPreset, sensor_preset
from spikegyro.sim.trajectory import TrajectoryConfig, random_trajectory

SPLITS = ("train", "val", "test")
WINDOW_US = 100_000
SCENE_KINDS = ("sparse", "office", "photo", "procedural")
"""The scene kinds, in the order of :attr:`spikegyro.sim.sensor.SensorPreset.scenes`; a sequence
file names its kind in the attribute ``scene_kind``."""
UNKNOWN_SCENE = "unknown"


@dataclass(frozen=True)
class SimConfig:
    """Everything that defines a dataset besides the seed and the number of sequences.

    Attributes:
        duration_ms: length of each sequence, milliseconds.
        camera: sensor intrinsics.
        trajectory: random-rotation distribution.
        events: sensor model; its nominal thresholds are replaced per sequence by draws from
            N(contrast_mean, contrast_std²) (ON and OFF independently, clamped at min_contrast).
        contrast_mean, contrast_std: per-sequence threshold distribution, log units.
        panoramas: folder of equirectangular images, or None for the bundled photographs.
        procedural_fraction: share of sequences on procedural panoramas.
        detail_strength: log-intensity std of the smooth texture added to photographs.
        val_fraction, test_fraction: share of sequences (and of folder panoramas) per split.
        sensor: sensor preset, ``ideal`` (the settings above) or ``davis240c`` (drawn per
            sequence; replaces the thresholds, noise, scene mix and detail strength above).
        scene_mix: weights of the scene kinds (:data:`SCENE_KINDS`: sparse, office, photo,
            procedural) instead of the sensor preset's; None keeps the preset's. Presets only.
    """

    duration_ms: int = 500
    camera: Camera = field(default_factory=Camera)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    events: EventSimConfig = field(default_factory=EventSimConfig)
    contrast_mean: float = 0.45
    contrast_std: float = 0.05
    panoramas: str | None = None
    procedural_fraction: float = 0.3
    detail_strength: float = 0.4
    val_fraction: float = 0.05
    test_fraction: float = 0.05
    sensor: str = "ideal"
    scene_mix: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.scene_mix is None:
            return
        mix = tuple(float(w) for w in self.scene_mix)
        if len(mix) != len(SCENE_KINDS) or min(mix) < 0 or sum(mix) <= 0:
            raise InputError(
                f"scene mix {self.scene_mix}: give {len(SCENE_KINDS)} weights >= 0 "
                f"({', '.join(SCENE_KINDS)}), not all 0."
            )
        if self.sensor == "ideal":
            raise InputError(
                "a scene mix needs a sensor preset (--sensor davis240c); the ideal sensor "
                "draws photographs and procedural scenes (--procedural-fraction)."
            )
        object.__setattr__(self, "scene_mix", mix)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable dict (round-trips through :meth:`from_dict`)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SimConfig:
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        data["camera"] = Camera(**data["camera"])
        data["trajectory"] = TrajectoryConfig(**data["trajectory"])
        data["events"] = EventSimConfig(**data["events"])
        if data.get("scene_mix") is not None:
            data["scene_mix"] = tuple(data["scene_mix"])
        return cls(**data)

    def panorama_splits(self) -> dict[str, list[Path]]:
        """The photographs available to each split."""
        paths = (
            bundled_panorama_paths() if self.panoramas is None else list_panoramas(self.panoramas)
        )
        return split_panoramas(paths, (self.val_fraction, self.test_fraction))


def split_counts(sequences: int, val_fraction: float = 0.05, test_fraction: float = 0.05):
    """Sequences per split: val and test get their fractions (at least 1 each from 3 on)."""
    if sequences < 3:
        return {"train": sequences, "val": 0, "test": 0}
    n_val = max(1, round(sequences * val_fraction))
    n_test = max(1, round(sequences * test_fraction))
    return {"train": sequences - n_val - n_test, "val": n_val, "test": n_test}


def sequence_rng(seed: int, split: str, index: int) -> np.random.Generator:
    """The generator of one sequence, independent of every other (split, index)."""
    return np.random.default_rng(np.random.SeedSequence([seed, SPLITS.index(split), index]))


@lru_cache(maxsize=16)
def _photo(path: str) -> Panorama:
    return load_panorama(path)


@lru_cache(maxsize=4)
def _splits(config: SimConfig) -> dict[str, list[Path]]:
    return config.panorama_splits()


def simulate_sequence(config: SimConfig, index: int, seed: int, split: str = "train") -> Recording:
    """Simulate sequence ``index`` of ``split``: a pure function of its arguments.

    Used by ``spikegyro simulate`` and usable for on-the-fly training data.
    """
    if split not in SPLITS:
        raise InputError(f"split '{split}': must be one of {', '.join(SPLITS)}.")
    preset = sensor_preset(config.sensor)
    rng = sequence_rng(seed, split, index)
    photos = _splits(config)[split]
    width = panorama_width(config.camera)
    sensor = None
    if preset is None:
        floor = config.events.min_contrast
        c_on, c_off = np.maximum(rng.normal(config.contrast_mean, config.contrast_std, 2), floor)
        if not photos or rng.random() < config.procedural_fraction:
            kind = "procedural"
            panorama = procedural_panorama(rng, width, name=f"procedural/{split}/{index}")
        else:
            kind = "photo"
            photo = _photo(str(photos[int(rng.integers(len(photos)))]))
            panorama = add_detail(photo, rng, config.detail_strength, width)
    else:
        sensor = preset.draw(rng, config.camera.width / 240)
        c_on, c_off = sensor.contrast_on, sensor.contrast_off
        mix = config.scene_mix or preset.scenes
        kind, panorama = _sensor_scene(preset, mix, rng, photos, width, f"{split}/{index}")
    duration_s = config.duration_ms / 1000.0
    trajectory = random_trajectory(rng, duration_s, config.trajectory)
    events_config = replace(config.events, contrast_on=float(c_on), contrast_off=float(c_off))
    rec = simulate(
        panorama, trajectory, config.camera, events_config, rng, duration_s, sensor=sensor
    )
    if sensor is not None:
        rec = _sensor_recording(rec, config, preset, sensor)
    n_windows = config.duration_ms // 100  # whole 100 ms windows only
    t = rec.events.t
    windows = np.bincount(t[t < n_windows * WINDOW_US] // WINDOW_US, minlength=n_windows)
    attrs = {
        **rec.attrs,
        "scene_kind": kind,
        "contrast_on": float(c_on),
        "contrast_off": float(c_off),
        "seed": int(seed),
        "split": split,
        "index": int(index),
        "r0": trajectory.r0.ravel().tolist(),
        "events_per_100ms": windows.tolist(),
        "omega_units": "rad/s",
        "time_units": "us",
        "generator": f"spikegyro {__version__}",
    }
    return Recording(events=rec.events, gyro=rec.gyro, attrs=attrs)


def _sensor_scene(
    preset: SensorPreset,
    mix: tuple[float, ...],
    rng: np.random.Generator,
    photos: list[Path],
    width: int,
    name: str,
) -> tuple[str, Panorama]:
    """A scene drawn with the weights ``mix``, and its kind: sparse shapes, office, photograph
    or procedural (:data:`SCENE_KINDS`)."""
    weights = np.array(mix, dtype=np.float64)
    if not photos:
        weights[SCENE_KINDS.index("photo")] = 0.0
        if not weights.any():
            raise InputError(f"scene {name}: the scene mix asks only for photographs, and this "
                             "split has none; give other kinds some weight.")  # fmt: skip
    kind = SCENE_KINDS[int(rng.choice(len(SCENE_KINDS), p=weights / weights.sum()))]
    if kind == "sparse":
        return kind, sparse_panorama(rng, width, name=f"sparse/{name}")
    if kind == "office":
        return kind, office_panorama(rng, width, name=f"office/{name}")
    if kind == "photo":
        photo = _photo(str(photos[int(rng.integers(len(photos)))]))
        return kind, add_detail(photo, rng, rng.uniform(*preset.detail_strength), width)
    return kind, procedural_panorama(rng, width, name=f"procedural/{name}")


def scene_kind(attrs: Mapping[str, Any]) -> str:
    """The scene kind (:data:`SCENE_KINDS`) of a sequence file's attributes, else ``unknown``.

    Files written before the ``scene_kind`` attribute existed name their generated scenes
    ``procedural/...``, ``sparse/...`` or ``office/...`` (attribute ``scene``) and their
    photographs by file stem, which holds no ``/``; files not made by ``spikegyro simulate``
    (real recordings) are ``unknown``.
    """
    kind = attrs.get("scene_kind")
    if kind in SCENE_KINDS:
        return str(kind)
    scene = attrs.get("scene")
    if not isinstance(scene, str) or not str(attrs.get("generator", "")).startswith("spikegyro"):
        return UNKNOWN_SCENE
    prefix = scene.split("/", 1)[0] if "/" in scene else "photo"
    return prefix if prefix in SCENE_KINDS else UNKNOWN_SCENE


def _sensor_recording(
    rec: Recording, config: SimConfig, preset: SensorPreset, sensor: SensorParams
) -> Recording:
    """Events of a drawn sensor, mapped onto the ideal pinhole if the preset says so."""
    calib = sensor.calibration(config.camera)
    events = rec.events
    if preset.undistort:
        cam = config.camera
        target = PinholeCamera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
        events = calib.map_events(events, target)
    attrs = {
        **rec.attrs,
        "sensor": config.sensor,
        "sensor_calib": list(astuple(calib)),  # fx fy cx cy k1 k2 p1 p2 k3, as calib.txt
        "events_on_pinhole": preset.undistort,
    }
    return Recording(events=events, gyro=rec.gyro, attrs=attrs)


def sequence_path(out: Path, split: str, index: int) -> Path:
    """Where sequence ``index`` of ``split`` lives."""
    return Path(out) / split / f"seq_{index:06d}.h5"


def _sensor_draws(attrs: Any) -> dict[str, float]:
    """The drawn ``sensor_*`` scalars of a sequence's attributes (none for the ideal sensor)."""
    return {
        k[len("sensor_") :]: float(v)
        for k, v in attrs.items()
        if k.startswith("sensor_") and np.ndim(v) == 0 and not isinstance(v, str)
    }


def _summary(rec: Recording) -> dict[str, Any]:
    speed = np.degrees(np.linalg.norm(rec.gyro.omega, axis=1)) if rec.gyro is not None else []
    return {
        "events": len(rec.events),
        "windows": list(rec.attrs["events_per_100ms"]),
        "speed_deg_s": float(np.mean(speed)),
        "key": f"{rec.attrs['split']}/{int(rec.attrs['index']):06d}",
        "sensor": _sensor_draws(rec.attrs),
    }


def _summary_from_file(path: Path) -> dict[str, Any]:
    with h5py.File(path, "r") as f:
        speed = np.degrees(np.linalg.norm(f["ang_xyz"][()], axis=1))
        return {
            "events": int(f["ev_ts"].shape[0]),
            "windows": [int(v) for v in f.attrs["events_per_100ms"]],
            "speed_deg_s": float(speed.mean()),
            "key": f"{f.attrs['split']}/{int(f.attrs['index']):06d}",
            "sensor": _sensor_draws(f.attrs),
        }


def _work(
    config_dict: dict[str, Any], seed: int, split: str, index: int, compression: str | None
) -> tuple[bytes, dict[str, Any]]:
    """One task (local process or Dask worker): the sequence file's bytes and its summary.

    The worker serialises (and compresses) the file itself, so the client only writes bytes.
    """
    import torch

    torch.set_num_threads(1)
    rec = simulate_sequence(SimConfig.from_dict(config_dict), index, seed, split)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_recording(Path(tmp) / "seq.h5", rec, compression=compression)
        return path.read_bytes(), _summary(rec)


def _statistics(summaries: list[dict[str, Any]]) -> dict[str, Any]:
    windows = np.array([w for s in summaries for w in s["windows"]], dtype=np.int64)
    speeds = np.array([s["speed_deg_s"] for s in summaries])
    if windows.size == 0:
        return {}
    q = np.percentile(windows, [0, 5, 25, 50, 75, 95, 100])
    rate = windows / (WINDOW_US / 1e6) / 1e6  # millions of events per second
    rate_q = np.percentile(rate, [1, 5, 25, 50, 75, 95, 99])
    stats: dict[str, Any] = {
        "events_per_s_millions": {
            **{f"p{p}": float(v) for p, v in zip((1, 5, 25, 50, 75, 95, 99), rate_q, strict=True)},
            # Real DAVIS240C rotation recordings (Event Camera Dataset) span 0.2 to 5.6 M/s.
            "fraction_in_0.2_5.6": float(((rate >= 0.2) & (rate <= 5.6)).mean()),
            "fraction_below_0.2": float((rate < 0.2).mean()),
        },
        "events_total": int(sum(s["events"] for s in summaries)),
        "events_per_100ms": {
            "mean": float(windows.mean()),
            **{f"p{p}": float(v) for p, v in zip((0, 5, 25, 50, 75, 95, 100), q, strict=True)},
            "fraction_below_1000": float((windows < 1000).mean()),
            "fraction_below_10000": float((windows < 10000).mean()),
        },
        "mean_omega_norm_deg_s": {
            "mean": float(speeds.mean()),
            "p99": float(np.percentile(speeds, 99)),
            "max": float(speeds.max()),
            "fraction_above_800": float((speeds > 800).mean()),
        },
    }
    draws = [x["sensor"] for x in summaries if x.get("sensor")]
    if draws:
        names = sorted(draws[0])
        table = np.array([[d[n] for n in names] for d in draws])
        stats["sensor_draws"] = {
            n: {"min": float(lo), "p50": float(mid), "max": float(hi)}
            for n, lo, mid, hi in zip(
                names, *np.percentile(table, [0, 50, 100], axis=0), strict=True
            )
        }
    return stats


def _sensor_table(summaries: list[dict[str, Any]]) -> dict[str, Any]:
    """Every sequence's drawn sensor, as columns and one row per ``split/index``."""
    rows = {x["key"]: x["sensor"] for x in summaries if x.get("sensor")}
    if not rows:
        return {}
    names = sorted(next(iter(rows.values())))
    return {"columns": names, "rows": {k: [v[n] for n in names] for k, v in rows.items()}}


def _write_meta(out: Path, meta: dict[str, Any]) -> None:
    with atomic_path(out / "meta.json") as tmp:
        tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")


def _check_resume(out: Path, meta: dict[str, Any]) -> None:
    path = out / "meta.json"
    if not path.exists():
        return
    old = json.loads(path.read_text())
    # Datasets made before sensor presets existed were made with the ideal sensor.
    old_config = {"sensor": "ideal", **old.get("config", {})}
    # ... and with the trajectory settings added since at their defaults (the random kind).
    moves = {**asdict(TrajectoryConfig()), **old_config.get("trajectory", {})}
    old_config["trajectory"] = moves
    if old_config != meta["config"] or old.get("seed") != meta["seed"]:
        raise InputError(
            f"{path}: this folder holds a dataset made with other options or another seed; "
            "choose another --out or delete the folder."
        )


Result = tuple[str, int, tuple[bytes, dict[str, Any]]]
Runner = Callable[[list[tuple[str, int]]], Iterator[Result]]


def _local_runner(config: SimConfig, seed: int, compression: str | None, workers: int) -> Runner:
    config_dict = config.to_dict()

    def run(tasks: list[tuple[str, int]]) -> Iterator[Result]:
        if workers <= 1:
            for split, index in tasks:
                yield split, index, _work(config_dict, seed, split, index, compression)
            return
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            futures = {
                pool.submit(_work, config_dict, seed, s, i, compression): (s, i) for s, i in tasks
            }
            for fut in as_completed(futures):
                yield (*futures[fut], fut.result())

    return run


def _dask_runner(config: SimConfig, seed: int, compression: str | None, scheduler: str) -> Runner:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError as err:
        raise InputError(
            "--scheduler needs Dask distributed: pip install 'spikegyro[distributed]'."
        ) from err

    config_dict = config.to_dict()

    def run(tasks: list[tuple[str, int]]) -> Iterator[Result]:
        with Client(scheduler) as client:
            futures = {
                client.submit(
                    _work, config_dict, seed, s, i, compression, key=f"seq-{s}-{i}-{seed}"
                ): (s, i)
                for s, i in tasks
            }
            for fut in dask_completed(futures):
                yield (*futures.pop(fut), fut.result())
                fut.release()

    return run


def generate_dataset(
    out: str | Path,
    sequences: int,
    seed: int = 0,
    config: SimConfig | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    on_sequence: Callable[[int, int, int], None] | None = None,
    compression: str | None = None,
) -> dict[str, Any]:
    """Write ``sequences`` sequences under ``out`` and return the metadata written to meta.json.

    Finished files are skipped (resume); files and meta.json are written atomically.

    Args:
        out: dataset folder.
        sequences: total number over train/val/test.
        seed: dataset seed.
        config: simulation options (default :class:`SimConfig`).
        workers: local processes (ignored with ``scheduler``).
        scheduler: address of a Dask distributed scheduler; workers must see the same
            ``config.panoramas`` path, the client writes the files.
        on_sequence: progress callback (done, total, events of the finished sequence).
        compression: HDF5 filter for the event datasets: None, "lzf" (about 2x smaller) or
            "gzip" (about 3.5x smaller, slower to write); any h5py reads them.
    """
    config = config or SimConfig()
    out = Path(out)
    counts = split_counts(sequences, config.val_fraction, config.test_fraction)
    splits = _splits(config)
    meta: dict[str, Any] = {
        "generator": "spikegyro simulate",
        "version": __version__,
        "seed": int(seed),
        "sequences": counts,
        "config": config.to_dict(),
        "panoramas": {s: [p.stem for p in splits[s]] for s in SPLITS},
        "layout": "DIR/{split}/seq_NNNNNN.h5; datasets ev_xy, ev_ts (us), ev_pol, ang_xyz "
        "(rad/s), ang_ts (us); attributes describe the sensor and the sequence",
        "complete": False,
    }
    run = (  # first: a missing Dask stops the run before anything is written
        _dask_runner(config, seed, compression, scheduler)
        if scheduler
        else _local_runner(config, seed, compression, workers)
    )
    _check_resume(out, meta)
    out.mkdir(parents=True, exist_ok=True)
    _write_meta(out, meta)
    summaries: list[dict[str, Any]] = []
    tasks = []
    for split in SPLITS:
        for index in range(counts[split]):
            path = sequence_path(out, split, index)
            if path.exists():
                summaries.append(_summary_from_file(path))
            else:
                tasks.append((split, index))
    done = len(summaries)
    for split, index, (data, summary) in run(tasks):
        with atomic_path(sequence_path(out, split, index)) as tmp:
            tmp.write_bytes(data)
        summaries.append(summary)
        done += 1
        if on_sequence is not None:
            on_sequence(done, sequences, summary["events"])
    meta.update(statistics=_statistics(summaries), complete=True)
    if config.sensor != "ideal":
        meta["sensor_draws"] = _sensor_table(summaries)
    _write_meta(out, meta)
    return meta


def export_official(
    src: str | Path,
    out: str | Path,
    window_ms: int = 100,
    on_file: Callable[[], None] | None = None,
) -> dict[str, int]:
    """Cut every sequence of dataset ``src`` into ``window_ms`` sample files under ``out``.

    Each sample is in exactly the official layout: events with t in [t0, t0 + window) shifted to
    start at 0 µs; ``ang_ts`` = 1000, 2000, ..., window (µs, the end of each 1 ms bin) and
    ``ang_xyz`` the ground truth there (rad/s). Files are ``out/{split}/NNNNNNN.h5``, numbered
    sequence index x samples per sequence + window index, with the source in attributes.
    Returns the number of samples per split.
    """
    src, out = Path(src), Path(out)
    if not (src / "meta.json").exists():
        raise InputError(f"{src}: no meta.json; give a folder made by 'spikegyro simulate'.")
    window_us = window_ms * 1000
    written = {}
    for split in SPLITS:
        files = sorted((src / split).glob("seq_*.h5")) if (src / split).is_dir() else []
        written[split] = 0
        for path in files:
            rec = read_recording(path)
            if rec.gyro is None:
                raise InputError(f"{path}: no ground truth (ang_xyz); cannot export it.")
            per_seq = int(rec.gyro.t[-1] // window_us)
            index = int(rec.attrs.get("index", path.stem.split("_")[-1]))
            for k in range(per_seq):
                t0 = k * window_us
                ang_ts = np.arange(1, window_ms + 1, dtype=np.int64) * 1000
                gyro = GyroTrace.from_arrays(ang_ts, rec.gyro.interpolate(t0 + ang_ts))
                sample = Recording(
                    events=rec.events.slice_time(t0, t0 + window_us).shift_time(-t0),
                    gyro=gyro,
                    attrs={
                        **{a: v for a, v in rec.attrs.items() if a != "events_per_100ms"},
                        "source": path.name,
                        "window": k,
                        "t0_us": t0,
                    },
                )
                write_recording(out / split / f"{index * per_seq + k:07d}.h5", sample)
                written[split] += 1
            if on_file is not None:
                on_file()
    meta = json.loads((src / "meta.json").read_text())
    meta["official_export"] = {"window_ms": window_ms, "samples": written, "source": str(src)}
    out.mkdir(parents=True, exist_ok=True)
    _write_meta(out, meta)
    return written
