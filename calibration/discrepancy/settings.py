"""The discrepancy workflow's settings, its null-calibrated thresholds and the error for data it cannot use."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from calibration.effects import CATALOGUE_VERSION

THRESHOLDS_PATH = Path(__file__).resolve().parent.parent / "discrepancy_thresholds.json"

#: Used only when no calibrated file exists (a fresh checkout before calibration): wide,
#: conservative values; the result says which were used.
FALLBACK_THRESHOLDS = {
    "identified": {"ljung_box": [200.0] * 3, "library_r2": [0.5] * 3, "gain": [0.3] * 3, "delta_bic": [50.0] * 3},
    "given_model": {"ljung_box": [200.0] * 3, "library_r2": [0.5] * 3, "gain": [0.3] * 3, "delta_bic": [50.0] * 3},
}

#: Slopes a (s/rad, s/m) of the Coulomb sign tanh(a dq / 2) tried for an identified baseline.
SLOPES = (100.0, 400.0, 1000.0, 3000.0)


class DiscrepancyError(ValueError):
    """Data the workflow cannot use (too short, not moving)."""


@dataclass
class Settings:
    cutoff: float = 10.0          # Hz
    order: int = 4
    heldout: float = 0.25         # fraction at the end
    max_effects: int = 4
    effort_lag: float = 1e-3      # s: the effort reported with a sample was computed from the state this much earlier
    thresholds: dict | None = None  # {"identified": {...}, "given_model": {...}}; None: the stored file


def load_thresholds(path: Path = THRESHOLDS_PATH) -> tuple[dict, str]:
    """The null-calibrated thresholds and where they came from. The thresholds depend on
    the catalogue (the best null candidate sets the gain and dBIC thresholds): a file
    calibrated with another catalogue version is still used, and its source says so."""
    try:
        doc = json.loads(Path(path).read_text())
        method = doc.get("method", {})
        source = f"{path} ({method.get('summary', 'null simulations')}"
        version = method.get("catalogue_version")
        if version != CATALOGUE_VERSION:
            source += (f"; calibrated with catalogue {version or 'before 1.2'}, this is {CATALOGUE_VERSION}: "
                       "recalibrate with python -m calibration.discrepancy_null")
        return doc["thresholds"], source + ")"
    except (OSError, KeyError, json.JSONDecodeError):
        return FALLBACK_THRESHOLDS, "built-in fallback (no calibrated threshold file)"
