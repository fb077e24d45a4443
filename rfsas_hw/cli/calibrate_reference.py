"""The reference transmitter's frames for ``rfsas calibrate --phase`` and ``--array``:
its angle from a turntable log or from a known position, the frames joined to it."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
import numpy.typing as npt
from rich.console import Console

from rfsas_hw.cli.options import comma_numbers
from rfsas_hw.records import ObservationBatch, Pose
from rfsas_hw.sources.csi_calibration import known_angle_deg, phase_frames


def reference_frames(
    console: Console,
    capture: str,
    *,
    flag: str,
    emitter: str | None,
    angles_path: Path | None,
    known_position: str | None,
    pose: str,
) -> tuple[ObservationBatch, npt.NDArray[np.float64]]:
    """The reference transmitter's frames in ``capture`` and the true angle of each,
    degrees from boresight; says on ``console`` how many frames were joined.

    Args:
        flag: the option being run (``--phase``, ``--array``), for messages.
        known_position: ``X_M,Y_M`` of the transmitter, or None with ``angles_path``.
        pose: the sensor's ``X_M,Y_M,HEADING_DEG`` (compass), for ``known_position``.

    Raises:
        click.UsageError: neither or both of ``angles_path`` and ``known_position``.
        ConfigError: a malformed position or pose.
        CalibrationError, SourceError, CaptureFormatError, DataFormatError: see
            :func:`~rfsas_hw.sources.csi_calibration.phase_frames`.
    """
    if (angles_path is None) == (known_position is None):
        raise click.UsageError(f"{flag} needs --angles LOG.csv or --known-position X,Y (one)")
    known = None
    if known_position is not None:
        x, y = comma_numbers(known_position, 2, "--known-position")
        px, py, heading = comma_numbers(pose, 3, "--pose")
        known = known_angle_deg(Pose(px, py, heading % 360.0), x, y)
        console.print(f"known transmitter at {known:+.2f}° from boresight")
    obs, true_deg, join = phase_frames(
        capture, emitter=emitter, angles_path=angles_path, known_deg=known
    )
    console.print(
        f"{join.used} frames with a known angle ({join.frames} in the recording, "
        f"{join.emitter_frames} from the reference, {join.outside_log} outside the angle log)"
    )
    return obs, true_deg
