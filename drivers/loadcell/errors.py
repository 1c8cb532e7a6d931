"""What a procedure stops on when the load cell fails: the `LoadCellError` family."""

from __future__ import annotations

from rig.faults import DeviceFault


class LoadCellError(DeviceFault):
    """Anything wrong with the load cell that a procedure should stop on."""


class LoadCellDisconnected(LoadCellError):
    """The port died, or no frame arrived within the stale timeout."""


class LoadCellCommandError(LoadCellError):
    """The device answered a command with an error reply, or did not answer."""


class LoadCellNotCalibrated(LoadCellError):
    """Newtons were asked for but no calibration is loaded."""
