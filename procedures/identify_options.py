"""The options of `rig identify` parsed: gravity, friction slope, position friction, effects from a model file."""

from __future__ import annotations

import math

import click
import numpy as np


def parse_gravity(text: str) -> str | np.ndarray:
    """'auto', 'config' or three numbers 'gx,gy,gz' (m/s^2)."""
    t = text.strip().lower()
    if t in ("auto", "config"):
        return t
    try:
        g = np.array([float(x) for x in t.replace(" ", "").split(",")])
    except ValueError:
        g = np.zeros(0)
    if g.shape != (3,) or not np.all(np.isfinite(g)) or np.linalg.norm(g) == 0:
        raise click.BadParameter(f"{text!r}: use 'auto', 'config' or three numbers 'gx,gy,gz' in m/s^2",
                                 param_hint="--gravity")
    return g


def parse_slope(text: str) -> str | float:
    t = text.strip().lower()
    if t == "auto":
        return t
    try:
        a = float(t)
    except ValueError:
        a = float("nan")
    if not (math.isfinite(a) and a > 0):
        raise click.BadParameter(f"{text!r}: use 'auto' or a slope > 0 s/rad", param_hint="--friction-slope")
    return a


def effects_from(parameters: dict) -> tuple[list, list[str]]:
    """The EffectTerms of --effects-from (none without it) and the lines of the effects left out."""
    path = str(parameters.get("effects_from") or "").strip()
    if not path:
        return [], []
    from calibration.identification import effect_terms
    from rig.model.model_file import ModelFileError, load_model

    try:
        entries = load_model(path).effects
    except ModelFileError as exc:
        raise click.BadParameter(str(exc), param_hint="--effects-from") from None
    if not entries:
        raise click.BadParameter(f"{path}: the model file has no effects to identify", param_hint="--effects-from")
    try:
        terms, left = effect_terms(entries, path)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--effects-from") from None
    if parse_position_friction(parameters["position_friction"]) is not None and \
            any(t.effect == "position_friction" and t.joint == 3 for t in terms):
        raise click.BadParameter(f"{path} has a joint-3 position friction and --position-friction is "
                                 f"{parameters['position_friction']!r}: use one of them", param_hint="--effects-from")
    return terms, left


def parse_position_friction(text: str):
    """'off' -> None, 'auto' -> 'auto', 'P' or 'P,K' -> (P m, K)."""
    t = str(text).strip().lower()
    if t in ("off", "", "none"):
        return None
    if t == "auto":
        return "auto"
    from calibration.effects import FRICTION_HARMONICS

    try:
        parts = [float(x) for x in t.split(",")]
    except ValueError:
        parts = []
    if len(parts) not in (1, 2) or not parts[0] > 0 or (len(parts) == 2 and parts[1] not in FRICTION_HARMONICS):
        raise click.BadParameter(f"{text!r}: give off, auto, a period in m (e.g. 0.05) or period,harmonics "
                                 f"(harmonics {FRICTION_HARMONICS[0]}-{FRICTION_HARMONICS[-1]})",
                                 param_hint="--position-friction")
    return (parts[0], int(parts[1]) if len(parts) == 2 else 1)
