"""A device's clock on the host's: block minima of (receipt - send) and the line under them."""

from __future__ import annotations

from collections import deque


class BlockMinima:
    """The smallest (receipt - send) of each block of `block_s` device seconds, the last `blocks` kept.

    A message is only ever delayed on its way, so receipt - send is the clock offset plus a
    non-negative delay, and a block's minimum is close to the offset."""

    def __init__(self, block_s: float, blocks: int) -> None:
        self.block_s = block_s
        self.closed: deque[tuple[float, float]] = deque(maxlen=blocks)
        self.current: tuple[float, float] | None = None
        self._start: float | None = None

    def add(self, t: float, d: float) -> None:
        """A message sent at device time `t` (s) that arrived `d` s later by the host's clock."""
        if self._start is None:
            self._start = t
        if self.current is None or d < self.current[1]:
            self.current = (t, d)
        if t - self._start >= self.block_s:
            self.closed.append(self.current)
            self._start, self.current = t, None


def envelope_line(pts, t: float) -> float:
    """At device time `t`, the line through the block minima `pts` ((t, d) pairs), shifted down
    onto their lower envelope (the fit runs through their mean)."""
    n = len(pts)
    mx = sum(p[0] for p in pts) / n
    my = sum(p[1] for p in pts) / n
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    slope = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx if sxx > 0 else 0.0
    resid = min(p[1] - (my + slope * (p[0] - mx)) for p in pts)
    return my + slope * (t - mx) + resid
