"""numba's first-use compilations, said in a run's progress lines."""

from __future__ import annotations

import sys
import time
from typing import Callable


class CompileWatch:
    """Say in the progress lines when numba compiles a kernel during the run.

    The simulated rig's step (rig.sim.kernel) is compiled at its first call, which
    falls in a procedure's first step that moves the rig ("attach the object" for
    cooperative): about 20 s on a 2-core machine, once after an install or upgrade
    (numba caches it), with no progress of its own. numba's event API reports every
    real compilation (not a load from its cache); without numba loaded there is
    nothing to watch. ``note(name, seconds)`` says it (seconds None: it starts)."""

    def __init__(self, note: Callable[[str, float | None], None]):
        self.note = note
        self._listener = None

    def start(self) -> None:
        if self._listener is not None or "numba" not in sys.modules:
            return
        try:
            from numba.core import event
        except ImportError:
            return
        self._listener = _compile_listener(event, self.note)
        event.register("numba:compile", self._listener)

    def stop(self) -> None:
        if self._listener is None:
            return
        from numba.core import event

        try:
            event.unregister("numba:compile", self._listener)
        except ValueError:
            pass
        self._listener = None


def _compile_listener(event, note: Callable[[str, float | None], None]):
    """A numba event listener calling note(name, None) when the outermost compilation of a
    kernel starts and note(name, seconds) when it ends (the kernels it calls are compiled
    inside it and not reported apart)."""

    class CompileListener(event.Listener):
        def __init__(self):
            self.depth = 0
            self.started = 0.0
            self.name = ""

        def on_start(self, ev):
            if self.depth == 0:
                fn = getattr(ev.data.get("dispatcher"), "py_func", None)
                self.name = (f"{getattr(fn, '__module__', '')}.{getattr(fn, '__qualname__', '')}"
                             if fn is not None else "a numba kernel")
                self.started = time.monotonic()
                note(self.name, None)
            self.depth += 1

        def on_end(self, ev):
            self.depth -= 1
            if self.depth == 0:
                note(self.name, time.monotonic() - self.started)

    return CompileListener()
