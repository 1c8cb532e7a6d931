"""Counts to newtons: a load cell's two-point calibration and its file."""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from drivers.loadcell.errors import LoadCellNotCalibrated

STANDARD_GRAVITY = 9.80665  # m/s^2


@dataclass(frozen=True)
class LoadCellCalibration:
    """counts -> newtons: force = (counts - zero_counts - tare_counts) * newtons_per_count.

    Built from two known masses m1, m2 (kg) hung from the cell, read as mean counts c1, c2:
    newtons_per_count = g (m2 - m1) / (c2 - c1), zero_counts = c1 - g m1 / newtons_per_count.
    `tare_counts` shifts the zero so that the load present at the last tare reads 0 N.
    """

    newtons_per_count: float
    zero_counts: float
    tare_counts: float = 0.0
    mass1_kg: float | None = None
    mass2_kg: float | None = None
    counts1: float | None = None
    counts2: float | None = None
    counts1_sem: float | None = None  # standard error of the mean counts at mass 1
    counts2_sem: float | None = None
    newtons_per_count_std: float | None = None  # 1-sigma, from the two standard errors
    g: float = STANDARD_GRAVITY
    created: str = ""
    device: str = ""

    @classmethod
    def from_two_points(cls, mass1_kg: float, counts1: float, mass2_kg: float, counts2: float,
                        counts1_sem: float = 0.0, counts2_sem: float = 0.0,
                        g: float = STANDARD_GRAVITY, device: str = "") -> "LoadCellCalibration":
        if not all(map(math.isfinite, (mass1_kg, mass2_kg, counts1, counts2))):
            raise ValueError("load-cell calibration: masses and counts must be finite numbers")
        if mass1_kg == mass2_kg:
            raise ValueError("load-cell calibration: the two masses must differ")
        dc = counts2 - counts1
        noise = math.hypot(counts1_sem, counts2_sem)
        if abs(dc) < max(5.0, 10.0 * noise):
            raise ValueError(
                f"load-cell calibration: counts changed by only {dc:.1f} between {mass1_kg} kg and "
                f"{mass2_kg} kg (noise {noise:.1f} counts); check that the mass hangs from the cell")
        k = g * (mass2_kg - mass1_kg) / dc
        from datetime import datetime, timezone
        return cls(newtons_per_count=k, zero_counts=counts1 - g * mass1_kg / k,
                   mass1_kg=mass1_kg, mass2_kg=mass2_kg, counts1=counts1, counts2=counts2,
                   counts1_sem=counts1_sem, counts2_sem=counts2_sem,
                   newtons_per_count_std=abs(k) * noise / abs(dc), g=g,
                   created=datetime.now(timezone.utc).isoformat(), device=device)

    def newtons(self, counts: float) -> float:
        return (counts - self.zero_counts - self.tare_counts) * self.newtons_per_count

    def with_tare(self, counts_at_zero: float) -> "LoadCellCalibration":
        """The same calibration, zeroed so that `counts_at_zero` reads 0 N."""
        return replace(self, tare_counts=counts_at_zero - self.zero_counts)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict, source: str = "calibration") -> "LoadCellCalibration":
        try:
            cal = cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})
        except TypeError as exc:
            raise LoadCellNotCalibrated(f"{source}: not a load-cell calibration ({exc})") from None
        for name in ("newtons_per_count", "zero_counts", "tare_counts"):
            v = getattr(cal, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise LoadCellNotCalibrated(f"{source}: field '{name}' must be a finite number, got {v!r}")
        if cal.newtons_per_count == 0:
            raise LoadCellNotCalibrated(f"{source}: field 'newtons_per_count' is zero")
        return cal

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "LoadCellCalibration":
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise LoadCellNotCalibrated(f"{path}: no such calibration file") from None
        except json.JSONDecodeError as exc:
            raise LoadCellNotCalibrated(f"{path}: line {exc.lineno}: not valid JSON ({exc.msg})") from None
        return cls.from_dict(data.get("calibration", data), source=str(path))
