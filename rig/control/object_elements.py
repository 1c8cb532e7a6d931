"""The object's elements between the arms: which a slave holds, and where they pull.

Two arms hold one element; three hold a triangle. A slave tracks the tension of its
element with the master (`tracked`), moving away from the master (`outward`). The element
between two slaves (`pairs`) is held half by each: its tension error is integrated into
an offset along it (`PairOffsets`), half by each of its slaves.
"""

from __future__ import annotations

import numpy as np


def length(v: np.ndarray) -> float:
    """|v|, at least 1e-9 m: what a direction between two tips is divided by."""
    return max(np.linalg.norm(v), 1e-9)


def _mean_of(values: np.ndarray, indices: list[int]) -> float:
    """Mean of values[indices] (0 for none): np.mean's dispatch costs more than the sum of the
    one or two elements a control step averages."""
    return float(sum(values[k] for k in indices) / len(indices)) if indices else 0.0


class ObjectElements:
    """The elements as pairs of arm names (the load cells' order), seen from each slave."""

    def __init__(self, elements: list[tuple[str, str]], master: str, slaves: list[str]):
        self.elements = list(elements)
        self.master = master
        self.mine = {s: [k for k, e in enumerate(self.elements) if s in e] for s in slaves}
        self.tracked = {s: [k for k in self.mine[s] if master in self.elements[k]] for s in slaves}
        self.pairs = {s: [k for k in self.mine[s] if k not in self.tracked[s]] for s in slaves}

    def __len__(self) -> int:
        return len(self.elements)

    def other(self, k: int, arm: str) -> str:
        a, b = self.elements[k]
        return b if a == arm else a

    def span(self, k: int, arm: str, tips: dict[str, np.ndarray]) -> np.ndarray:
        """From the other arm of element k to `arm` (world, m)."""
        return tips[arm] - tips[self.other(k, arm)]

    def direction(self, k: int, arm: str, tips: dict[str, np.ndarray]) -> np.ndarray:
        d = self.span(k, arm, tips)
        return d / length(d)

    def neighbour_directions(self, arm: str, tips: dict[str, np.ndarray]) -> list[np.ndarray]:
        """Unit vectors from each arm `arm` shares an element with, to `arm`."""
        return [self.direction(k, arm, tips) for k, e in enumerate(self.elements) if arm in e]

    def outward(self, slave: str, tips: dict[str, np.ndarray]) -> np.ndarray:
        """Unit vector (world) along which the slave's target moves to raise its tension:
        away from the master along their element."""
        v = tips[slave] - tips[self.master]
        return v / length(v)

    def tracked_mean(self, values: np.ndarray, slave: str) -> float:
        """The mean of `values` over the elements the slave tracks."""
        return _mean_of(values, self.tracked[slave])


class PairOffsets:
    """Offsets (m) of each slave along its slave-slave elements: each element's tension
    error integrated, half by each of its two slaves, within +-`limit`."""

    def __init__(self):
        self.x_g: dict[tuple[str, int], float] = {}

    def reset(self) -> None:
        self.x_g.clear()

    def get(self, slave: str, k: int) -> float:
        return self.x_g.get((slave, k), 0.0)

    def integrate(self, slave: str, k: int, error: float, rate: float, k_i: float, deadband: float,
                  k_damp: float, dt: float, limit: float) -> None:
        """Integrate element k's tension `error` (N) and `rate` (N/s) over `dt` s."""
        g = 0.5 * k_i * (error - np.sign(error) * deadband) if abs(error) > deadband else 0.0
        r_k = g - 0.5 * k_damp * rate
        self.x_g[(slave, k)] = min(max(float(self.get(slave, k) + dt * r_k), -limit), limit)
