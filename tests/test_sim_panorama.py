"""Panorama loading, resolution handling and procedural scenes."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from spikegyro.errors import InputError
from spikegyro.sim import Camera, load_panorama
from spikegyro.sim.dataset import SimConfig, generate_dataset, sequence_path
from spikegyro.sim.panorama import bundled_panorama_paths
from spikegyro.sim.procedural import fractal_noise, panorama_width
from spikegyro.sim.render import prefilter


def test_load_8bit_luminance_npy_radiance_and_errors(tmp_path):
    rgb = np.zeros((8, 16, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 255, 128, 0
    Image.fromarray(rgb).save(tmp_path / "a.png")
    pano = load_panorama(tmp_path / "a.png")
    expected = (0.299 * 255 + 0.587 * 128) / 255
    np.testing.assert_allclose(pano.intensity, expected, rtol=1e-6)
    np.save(tmp_path / "hdr.npy", np.full((8, 16), 37.5, np.float32))
    assert load_panorama(tmp_path / "hdr.npy").intensity.max() == pytest.approx(37.5)
    Image.fromarray(rgb[:, :8]).save(tmp_path / "square.png")
    with pytest.raises(InputError, match="2:1"):
        load_panorama(tmp_path / "square.png")
    with pytest.raises(InputError, match="no such"):
        load_panorama(tmp_path / "missing.jpg")
    assert len(bundled_panorama_paths()) == 12


def test_prefilter_matches_the_camera_pixel_and_keeps_the_mean():
    cam = Camera()  # 1 / 200 rad per pixel: one panorama texel per pixel at width ~1257
    fine = np.random.default_rng(0).uniform(0, 1, (2048, 4096)).astype(np.float32)
    small = prefilter(fine, cam)
    assert (
        abs(small.shape[1] - 2 * np.pi * 200) < 30 and abs(small.shape[1] - 2 * small.shape[0]) <= 1
    )
    assert small.mean() == pytest.approx(fine.mean(), abs=1e-3)
    assert small.std() < fine.std() / 2  # averaged, not subsampled
    coarse = fine[:512, :1024]
    assert prefilter(coarse, cam) is coarse
    assert panorama_width(cam) == 1280


def test_fractal_noise_has_the_requested_spectrum_and_wraps():
    rng = np.random.default_rng(1)
    f = fractal_noise(256, 512, rng, beta=2.0)
    assert abs(f.mean()) < 1e-6 and f.std() == pytest.approx(1.0, abs=1e-5)
    power = np.abs(np.fft.rfft2(f)) ** 2
    freq = np.hypot(np.fft.rfftfreq(512)[None, :] * 512, 2 * np.fft.fftfreq(256)[:, None] * 256)
    # Power per frequency cell ∝ 1/f^β: an octave up divides it by about 2^β = 4.
    ratio = power[(freq >= 8) & (freq < 16)].mean() / power[(freq >= 16) & (freq < 32)].mean()
    assert 3.0 < ratio < 5.3
    # Periodic in longitude: the seam step is as small as any other column step.
    seam = np.abs(f[:, 0] - f[:, -1]).mean()
    assert seam < 2 * np.abs(np.diff(f, axis=1)).mean()


def test_a_panorama_folder_feeds_each_split_its_own_images(tmp_path):
    folder = tmp_path / "panos"
    folder.mkdir()
    for i in range(6):
        img = np.random.default_rng(i).integers(0, 255, (64, 128), dtype=np.uint8)
        Image.fromarray(img).save(folder / f"p{i}.png")
    cfg = SimConfig(
        duration_ms=100,
        camera=Camera.scaled(32, 24),
        panoramas=str(folder),
        procedural_fraction=0.0,
        val_fraction=0.2,
        test_fraction=0.2,
    )
    meta = generate_dataset(tmp_path / "ds", 5, seed=2, config=cfg)
    names = meta["panoramas"]
    assert sum(len(v) for v in names.values()) == 6
    assert not set(names["train"]) & (set(names["val"]) | set(names["test"]))
    from spikegyro.events.io import read_recording

    for split in ("train", "val", "test"):
        for i in range(meta["sequences"][split]):
            scene = read_recording(sequence_path(tmp_path / "ds", split, i)).attrs["scene"]
            assert scene.split("+")[0] in names[split]
