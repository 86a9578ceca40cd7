"""Equirectangular panoramas: loading, the bundled scene set, splits by panorama, mirroring.

An equirectangular image of H x W pixels covers longitude [−π, π) left to right and latitude from
straight up (top row) to straight down (bottom row). World directions use the camera axes at
identity orientation (x right, y down, z forward): longitude = atan2(x, z), and "up" is −y.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from PIL import Image

from spikegyro.errors import InputError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp", ".npy")
_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)

# The bundled photographs, split by panorama: one outdoor city scene for validation and one
# interior for testing; the other ten train.
BUNDLED_SPLITS = {
    "val": ("potsdamer_platz",),
    "test": ("st_fagans_interior",),
}


@dataclass(frozen=True)
class Panorama:
    """A luminance panorama.

    Attributes:
        intensity: (H, W) float32, linear in the stored pixel values: 8-bit images scaled to
            [0, 1], float images (.npy) taken as radiance.
        name: where it came from (file stem or a procedural tag), stored in sequence files.
    """

    intensity: np.ndarray
    name: str

    def __post_init__(self) -> None:
        img = np.asarray(self.intensity, dtype=np.float32)
        if img.ndim != 2 or img.shape[0] < 2 or img.shape[1] < 2:
            raise InputError(f"panorama {self.name}: expected an (H, W) image, got {img.shape}.")
        object.__setattr__(self, "intensity", img)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in pixels."""
        return self.intensity.shape  # type: ignore[return-value]


def luminance(image: np.ndarray) -> np.ndarray:
    """Rec. 601 luma of an (H, W, 3) image, or the image itself when already (H, W)."""
    if image.ndim == 3:
        return image[..., :3].astype(np.float32) @ _LUMA
    return image.astype(np.float32)


def load_panorama(path: str | Path) -> Panorama:
    """Read an equirectangular image as luminance.

    8-bit images are scaled to [0, 1], 16-bit to [0, 1] as well; ``.npy`` float arrays (H, W) or
    (H, W, 3) are taken as linear radiance (HDR). Radiance .hdr files are not read (Pillow cannot);
    convert them to .npy first.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such panorama file.")
    try:
        if path.suffix.lower() == ".npy":
            img = luminance(np.load(path, allow_pickle=False))
        else:
            with Image.open(path) as im:
                if im.mode in ("I;16", "I;16B", "I"):
                    img = np.asarray(im, dtype=np.float32) / 65535.0
                else:
                    img = luminance(np.asarray(im.convert("RGB"))) / 255.0
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the image ({exc}).") from None
    h, w = img.shape[:2]
    if abs(w - 2 * h) > 0.02 * w:
        raise InputError(
            f"{path}: {w}x{h} is not an equirectangular (2:1) panorama; crop or resize it."
        )
    if not np.isfinite(img).all() or img.min() < 0:
        raise InputError(f"{path}: pixel values must be finite and non-negative.")
    return Panorama(img, path.stem)


def mirror_panorama(panorama: Panorama, axis: int) -> Panorama:
    """The panorama of the world mirrored across the plane normal to camera axis ``axis``.

    ``axis=0`` (x) negates longitude: a left-right flip of the image. ``axis=1`` (y) negates
    latitude: an upside-down flip. Rendered through :meth:`Trajectory.mirrored` with the same
    axis, and a camera whose principal point is the image centre (cx = (W − 1) / 2), it yields the
    flipped event stream exactly.
    """
    if axis not in (0, 1):
        raise ValueError("mirror axis must be 0 (x, horizontal flip) or 1 (y, vertical flip)")
    flipped = panorama.intensity[:, ::-1] if axis == 0 else panorama.intensity[::-1, :]
    return Panorama(np.ascontiguousarray(flipped), f"{panorama.name}:mirror{'xy'[axis]}")


def bundled_panorama_paths() -> list[Path]:
    """The 12 CC0 photographs shipped with the package (see data/scenes/PROVENANCE.md)."""
    folder = Path(str(resources.files("spikegyro") / "data" / "scenes"))
    return sorted(p for p in folder.iterdir() if p.suffix.lower() == ".jpg")


def list_panoramas(folder: str | Path) -> list[Path]:
    """Image files (sorted by name) in ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder of panoramas.")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not paths:
        raise InputError(
            f"{folder}: holds no images ({', '.join(IMAGE_SUFFIXES)}); give a folder of "
            "equirectangular panoramas."
        )
    return paths


def split_panoramas(
    paths: list[Path], fractions: tuple[float, float] = (0.05, 0.05), seed: int = 0
) -> dict[str, list[Path]]:
    """Assign whole panoramas to train/val/test.

    The bundled set uses :data:`BUNDLED_SPLITS`. Any other set is shuffled with ``seed`` and cut
    by the (val, test) ``fractions``, with at least one panorama in val and test when there are
    three or more; with fewer, every split uses all of them (and the overlap is the user's call).
    """
    bundled = {p.stem for p in bundled_panorama_paths()}
    if {p.stem for p in paths} == bundled:
        held = {name for names in BUNDLED_SPLITS.values() for name in names}
        out = {"train": [p for p in paths if p.stem not in held]}
        for split, names in BUNDLED_SPLITS.items():
            out[split] = [p for p in paths if p.stem in names]
        return out
    if len(paths) < 3:
        return {"train": list(paths), "val": list(paths), "test": list(paths)}
    order = np.random.default_rng(seed).permutation(len(paths))
    n_val = max(1, round(fractions[0] * len(paths)))
    n_test = max(1, round(fractions[1] * len(paths)))
    shuffled = [paths[i] for i in order]
    return {
        "val": sorted(shuffled[:n_val]),
        "test": sorted(shuffled[n_val : n_val + n_test]),
        "train": sorted(shuffled[n_val + n_test :]),
    }
