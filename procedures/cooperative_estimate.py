"""The model's tension estimate in a cooperative run (issue 47): the source the loop is
handed (`calibration.tension_estimate`) and its figures beside the load cell."""

from __future__ import annotations

import numpy as np


def stamps(js: dict, n: int) -> np.ndarray:
    """When the model's tension estimate was measured: the oldest arm's joint state (s)."""
    return np.full(n, min(float(s.t) for s in js.values()))


def tension_source_for(dyn, effects, stick, rcm_frames, names, elements, tolerance: float, obj: dict):
    """The model's tension estimate of the object (issue 47): each arm's tip force from its
    joints and efforts (calibration.tension_estimate), each arm on its own model, effects
    and stick-slip terms (dicts by arm, or one for all), carried by the object's stretch
    (its `[object]` stiffness, N/m; a string pulls only) where stuck joints hide it. It is
    ambiguous where the torques' spread exceeds half the run's hold `tolerance` (N)."""
    from calibration.tension_estimate import tension_source

    return tension_source(dyn, effects, stick, rcm_frames, names, elements, ambiguous_spread=0.5 * tolerance,
                          stiffness=float(obj["stiffness"]), pulls_only=obj["kind"] == "string")


def estimate_figures(log, params, source: str, cell: bool, estimate) -> dict:
    """The model's estimate beside the load cell while the master moves (RMS and largest
    difference, bias; N), what the loop closed on, the share of ticks it was ambiguous and
    the estimate's median spread (N)."""
    from calibration.tension_estimate import tension_figures

    doc = {"source": source, "loop_closed_on": "model estimate" if source == "model" else "load cell",
           "estimator": "generalized-momentum observer per arm on the model, J^-T, least squares over the arms, "
                        "carried by the object's stretch (calibration.stretch_filter)",
           "ambiguous_share": float(np.mean(log["estimate_ambiguous"])) if len(log["t"]) else None,
           "ambiguous_means": f"the tension's spread beyond {estimate.ambiguous_spread:g} N (stuck joints' static "
                              "friction, which the model cannot place in its band), a joint at a limit or a "
                              "singular Jacobian: contact and model error look alike there, and the object's "
                              "stretch carries the estimate",
           "spread_median": float(np.median(log["estimate_spread"])) if len(log["t"]) else None}
    if estimate.stretch is not None:
        doc["stiffness_configured"] = estimate.stretch.k0.tolist()
        doc["stiffness_followed"] = estimate.stretch.k.tolist()
    if cell:
        m0 = params["settle"]
        doc.update(tension_figures(log["t"], log["tension_estimate"], log["tension"], m0, m0 + params["duration"])
                   or {})
    else:
        doc["note"] = "no load cell: the tension figures of this run are the estimate's own"
    return doc
