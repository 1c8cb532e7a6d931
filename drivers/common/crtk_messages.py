"""Whether the dVRK's CRTK messages (the package's `crtk_msgs`) load in this interpreter.

A dVRK arm over ROS 2 needs them: its operating state (enable, home, FAULT), its state
commands and `servo_ci` are crtk_msgs types. `crtk_msgs` ships its compiled libraries per
Python ABI (see its docstring); on a Python they were not built for its import fails, and a
procedure that went on without them would never enable or home the arms. `problem()` gives
the one line that names the Python and the fix, for every command that needs them to stop
on before it opens anything.
"""

from __future__ import annotations

import sys

_problem: str | None = None
_checked = False


def problem() -> str | None:
    """None when `crtk_msgs` loads here; else one line naming this Python and what to do."""
    global _problem, _checked
    if not _checked:
        try:
            import crtk_msgs.msg  # noqa: F401
            import crtk_msgs.srv  # noqa: F401
        except ImportError as exc:
            text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            _problem = text if text.startswith("crtk_msgs") else (
                f"crtk_msgs cannot load on Python {sys.version_info.major}.{sys.version_info.minor} ({text}); "
                "reinstall with `pip install -e .` in a venv of Python 3.11, 3.12 or 3.13")
        _checked = True
    return _problem


def required(what: str) -> None:
    """Raise ImportError with `problem()`'s line, prefixed by what needs the messages."""
    why = problem()
    if why is not None:
        raise ImportError(f"{what} needs the dVRK's CRTK messages: {why}")
