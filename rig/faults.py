"""The one base class of device faults: a device stopped answering or answered nonsense.

A stale arm stream, a load cell whose cable came out, a pty that is not a load cell, a
mocap bridge that went quiet, an operator who never answered, a stream that never
arrived: each driver raises its own subclass of `DeviceFault` with one line naming the
device and what to check. The run engine (`rig.run`) records such a run as aborted (the
arms it moved are held, the recording is closed with the line as its reason) and the
command prints the line and exits non-zero, without a traceback.
"""

from __future__ import annotations


class DeviceFault(RuntimeError):
    """A device fault; str(fault) is one line for a person (device, what happened, what to check)."""
