"""The one error a fit raises when the data cannot support it.

A fit that is poorly conditioned (too little range of motion, too few frames, too many
occluded samples, a degenerate geometry) refuses with a FitError that says what is
missing and by how much, instead of returning a silently poor answer (issue 4, "Bad
input"). `condition` carries the measured figures so a procedure can report them.
"""

from __future__ import annotations


class FitError(ValueError):
    """A fit refused because its data do not determine the answer well enough."""

    def __init__(self, message: str, condition: dict | None = None):
        super().__init__(message)
        self.condition = dict(condition or {})
