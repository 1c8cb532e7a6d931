"""The plain model `rig discrepancy` judges effects against: the training block and the fit of
`rig identify --csv` at its defaults, and model files held in memory (the workflow's own
model, a plain model with other parameters)."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from calibration.signals import settling_samples


def plain_training_block(q, dq, tau, rate: float, heldout: float, breaks=(), source: str = "the data"):
    """The training block as `rig identify --csv` takes it, processed with its filter: the
    first 1 - ``heldout`` of the record less a guard of one settling length (several pieces:
    each filtered on its own, the first share of their samples)."""
    from calibration.datasets import JointData, processed, split_blocks
    from calibration.identification import CUTOFF_HZ, FILTER_ORDER

    data = JointData(np.arange(len(q)) / rate, np.asarray(q, float), np.asarray(dq, float),
                     np.asarray(tau, float), rate, source)
    if len(breaks):
        from calibration.datasets import pieces_training_block

        return pieces_training_block(data, breaks, CUTOFF_HZ, FILTER_ORDER, heldout)
    train_all, _ = split_blocks(processed(data, CUTOFF_HZ, FILTER_ORDER), heldout)
    guard = min(settling_samples(rate, CUTOFF_HZ, FILTER_ORDER), train_all.n_samples // 4)
    return train_all.rows(slice(0, train_all.n_samples - guard), f"minus a {guard}-sample guard")


def plain_fit(train):
    """`rig identify --csv`'s fit at its defaults on processed training data: a FitOutcome."""
    from calibration.identification import DEADBAND, fit_identification

    return fit_identification(train, "auto", "auto", deadband=DEADBAND, parallel=True, stribeck=True)


def _model_in_memory(plain, standard, slope: float, gravity, stribeck, effects):
    """A model file (in memory, on ``plain``'s path and provenance) with these standard
    parameters (82,), smooth-sign slope, gravity (3,), Stribeck term ({"Fst", "vs"} or None)
    and effects entries, laid out as `rig.model.model_file.save_model` writes it."""
    import tempfile
    from pathlib import Path

    from rig.model.model_file import load_model, save_model

    with tempfile.TemporaryDirectory() as tmp:
        m = load_model(save_model(Path(tmp) / "model.json", standard=standard, names=plain.names, slope=slope,
                                  gravity=gravity, stribeck=stribeck, gravity_source="estimated",
                                  provenance_info=plain.document.get("provenance", {}),
                                  extra={"effects": list(effects)}))
    return replace(m, path=plain.path)


def workflow_model(plain, workflow, result: dict):
    """The workflow's own model (its rigid body fitted again with its effects, physically
    consistent: `Discrepancy.augmented`) as a model file in memory, on ``plain``'s
    document: with an identified baseline its smooth-sign slope and no Stribeck excess (the
    workflow's baseline has none); with a given one, the given model's terms and effects."""
    pi, entries = workflow.augmented(result)
    doc = copy.deepcopy(plain.document)
    doc["standard_parameters"] = dict(doc.get("standard_parameters", {}), values=np.asarray(pi).tolist())
    if workflow.mode == "identified":
        doc["friction"] = {"slope": float(workflow.slope)}
        doc["effects"] = entries
        return replace(plain, standard=np.asarray(pi, float), slope=float(workflow.slope), document=doc)
    doc["effects"] = list(plain.effects) + entries
    return replace(plain, standard=np.asarray(pi, float), document=doc)


def _relative(model, motion, settings) -> np.ndarray:
    """A model's relative error per joint on a motion (calibration.generalisation.Motion)."""
    from calibration.prediction import predict

    return np.asarray(predict(model, motion.q, motion.dq, motion.tau, motion.rate, settings,
                              motion.source).figures("all")["relative_error"], float)
