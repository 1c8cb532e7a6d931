"""The plain model identified again with effects in its regressor, for `rig discrepancy`'s
gate (calibration.generalisation.EffectGate): the effects' columns beside the rigid body's,
chosen on the other motions when that predicts better than the plain model with the
effects fitted on top."""

from __future__ import annotations

import numpy as np

from calibration.effects import CATALOGUE
from calibration.plain_model import _model_in_memory, _relative


def identified_with(gate, subset):
    """The plain model identified again on its training block with ``subset``'s effects in
    the regressor (`calibration.identification.fit_identification(effects=...)`): the
    gravity direction, friction slope, Stribeck velocity and rigid body chosen with the
    effects' columns beside them, the effects' amplitudes fitted with them (at the
    workflow's non-linear parameters). A plain model fitted without an effect has taken up
    what it could of it everywhere: an unmodelled spring on the insertion joint tilted
    the chosen gravity by 26 degrees on the simulated rig and left joints 1-2 predicted 4-8
    times worse than without the spring; fitted together, every joint came back to its
    floor. A delay's column is built from the plain model's torque; a play, which needs
    the model's mass matrix too, is carried with the parameters fitted on top of the plain
    model; effects that are terms of the rigid body (an offset, a payload) are taken up
    by it. A stiction effect on joint 3 replaces the Stribeck column. Returns (model file in memory, the effects it carries, reasons of
    the effects whose amplitudes left the catalogue's range) or None when no effect of
    ``subset`` can be identified this way (or its columns and the rigid body's are not
    separable on the training motion). Cached."""
    from calibration.base_params import RankDeficientError
    from calibration.identification import DEADBAND, STRIBECK_JOINT, EffectTerm, fit_identification

    key = ("identified",) + gate._key(subset)
    if key in gate._cache:
        return gate._cache[key]
    torque = gate._plain_torque()
    terms = [EffectTerm(a.effect, a.joint, a.grid, tuple(bool(x) for x in a.free), torque) for a in subset
             if EffectTerm.identifiable(a.effect, with_model_torque=True)]
    out = None
    if terms:
        stribeck = not any(t.effect == "stiction" and t.joint - 1 == STRIBECK_JOINT for t in terms)
        try:
            fit = fit_identification(gate.training, "auto", "auto", deadband=DEADBAND, parallel=True,
                                     stribeck=stribeck, effects=terms)
        except RankDeficientError:
            # an effect's columns and the rigid body's are not separable on this motion
            gate._cache[key] = None
            return None
        entries = fit.effect_entries("identified with the rigid body (rig discrepancy)")
        implausible = [f"{e['name']}@{e['joint']}: {why}" for e in entries
                       if (why := CATALOGUE[e["name"]].sanity(e["params"], e["joint"])) is not None]
        carried = [a for a in subset if not EffectTerm.identifiable(a.effect, with_model_torque=True)
                   and not CATALOGUE[a.effect].in_rigid_body_model and a.effect != "payload"]
        on_top = gate.fit(subset)["entries"]
        entries += [e for a, e in zip(subset, on_top) if any(a is c for c in carried)]
        sdp = fit.fits["sdp"]
        out = (_model_in_memory(gate.plain, sdp.pi, fit.slope, fit.gravity, fit.stribeck(), entries),
               [a for a in subset if EffectTerm.identifiable(a.effect, with_model_torque=True)] + carried,
               implausible)
    gate._cache[key] = out
    return out


def identified_choice(gate, kept, dropped, plain, written):
    """The best of the plain model identified again with ``kept``, and with ``kept`` and
    the identifiable effects ``dropped`` as not confirmed, on the other motions: written
    when it predicts every joint no worse than the plain model and the whole at least
    CONFIRM_GAIN better than ``written`` (a larger set only when at least CONFIRM_GAIN
    better than the smaller). Returns (model, effects, relative errors, tried) or None."""
    from calibration.generalisation import CONFIRM_GAIN
    from calibration.identification import EffectTerm

    sets = [list(kept)]
    extra = [a for a in dropped if EffectTerm.identifiable(a.effect, with_model_torque=True)
             and not any(a is k for k in kept)]
    if extra:
        sets.append(list(kept) + extra)
    best, tried = None, []
    for subset in sets:
        got = gate.identified_with(subset)
        if got is None:
            continue
        model, effects, implausible = got
        if implausible:
            # an amplitude out of range: those effects out, the others identified again
            bad = {x.split(":")[0] for x in implausible}
            subset = [a for a in subset if f"{a.effect}@{a.joint}" not in bad]
            got = gate.identified_with(subset)
            if got is None or got[2]:
                tried.append({"effects": [f"{a.effect}@{a.joint}" for a in effects], "implausible": implausible})
                continue
            model, effects, _ = got
        rel = np.mean([_relative(model, m, gate.settings) for m in gate.motions], axis=0)
        tried.append({"effects": [f"{a.effect}@{a.joint}" for a in effects], "relative_error": rel.tolist()})
        ok = np.all(rel <= plain) and rel.sum() < (1.0 - CONFIRM_GAIN) * written.sum()
        if ok and (best is None or rel.sum() < (1.0 - CONFIRM_GAIN) * best[2].sum()):
            best = (model, effects, rel)
    return None if best is None else best + (tried,), tried
