"""What goes wrong with a NatNet stream: the `NatNetError` family."""

from __future__ import annotations

from rig.faults import DeviceFault


class NatNetError(DeviceFault):
    """Anything wrong with the NatNet stream that a procedure should stop on (one line)."""


class NatNetConnectError(NatNetError):
    """No server answered, or it does not have the rigid bodies asked for."""


class NatNetVersionError(NatNetError):
    """The server streams a bitstream version this driver does not decode."""


class NatNetDecodeError(ValueError):
    """A packet that does not decode; `kind` is "truncated", "trailing" or "malformed"."""

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind
