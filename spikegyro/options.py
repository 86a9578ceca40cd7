"""Command-line options that several commands share, defined once so that each reads, checks
and is documented the same way wherever it appears (a Typer option object may serve any
number of commands)."""

from __future__ import annotations

import typer

IMU_TO_CAMERA_HELP = (
    "Rotation from the IMU's axes to the camera's (x right, y down, z forward): signed axes, one "
    "per camera axis, e.g. '-x,-y,z' for omega_cam = (-gx, -gy, gz), or 9 numbers, the rows of "
    "R with omega_cam = R omega_imu (`spikegyro calibrate-imu` estimates it). Default: text and "
    "HDF5 gyros are in the camera frame; a camera file's IMU gets its camera's known rotation "
    "(jAER DAVIS240: -x,-y,z), else stays in IMU axes with a warning."
)
"""Help text of the ``--imu-to-camera`` option, shared by every command that reads a gyro."""

INTRINSICS = typer.Option(
    None, "--intrinsics", help="Sensor pinhole intrinsics fx fy cx cy (pixels), no distortion."
)
"""``--intrinsics FX FY CX CY``: a pinhole calibration without distortion, pixels."""

IMU_TO_CAMERA = typer.Option(None, "--imu-to-camera", help=IMU_TO_CAMERA_HELP)
"""``--imu-to-camera R``: the gyro's axes in the camera frame
(:func:`spikegyro.events.imu.imu_rotation`)."""

START = typer.Option(0.0, "--start", help="Start, seconds after the first event.")
"""``--start S``: where a recording's span starts, seconds after its first event."""

END = typer.Option(None, "--end", help="End, seconds after the first event.")
"""``--end S``: where it ends, seconds after the first event (default: the last event)."""

WIDTH = typer.Option(None, help="Sensor width, pixels (text files default to 240).")
"""``--width``: the sensor width of event files that do not say (see
:func:`spikegyro.checks.sensor_option`)."""

HEIGHT = typer.Option(None, help="Sensor height, pixels (text files default to 180).")
"""``--height``: the sensor height of event files that do not say."""

CLOCK = typer.Option(
    None,
    "--clock",
    help="Run the network on this clock instead of its own: paper (1 ms steps) or "
    "events:N[:MIN-MAX] (a step closes after N events, within MIN-MAX ms).",
)
"""``--clock``: the spiking network's clock (:meth:`spikegyro.events.clock.Clock.parse`)."""

PIXELS = typer.Option(
    None,
    "--pixels",
    help="With a calibration, the network reads the sensor's own pixels (sensor: a window around "
    "the principal point, the focal length corrected at the output) or events reprojected onto "
    "its camera (model). Default: the checkpoint's choice.",
)
"""``--pixels``: how a calibrated sensor's events reach the network
(:data:`spikegyro.stream.predict.PIXELS`)."""
