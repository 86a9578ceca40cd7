"""``spikegyro export-nir``: SNN-6 as a Neuromorphic Intermediate Representation file."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from spikegyro.checks import check_output_file
from spikegyro.models.nir import export_nir
from spikegyro.pretrained import checkpoint_help


def export_nir_command(
    checkpoint: Path = typer.Argument(
        ..., help=checkpoint_help("spikegyro SNN-6 checkpoint", None)
    ),
    out: Path = typer.Argument(..., help="Output NIR file (HDF5, e.g. snn6.nir)."),
) -> None:
    """Write SNN-6 as a NIR graph (CubaLIF neurons; needs the 'nir' extra).

    The refractory kernel and the 1 ms sampling are not exact in NIR: see docs/nir.md.
    """
    check_output_file(out, "OUT")
    path = export_nir(checkpoint, out)
    Console(stderr=True).print(
        f"wrote {path}: SNN-6 as NIR (Conv2d + CubaLIF x 5, AvgPool2d, Linear, CubaLI)"
    )
