"""Refitting an added effect's non-linear parameter (`Discrepancy._refine_added`)."""

import numpy as np

from calibration.discrepancy.settings import Settings
from calibration.discrepancy.workflow import Discrepancy
from calibration.discrepancy_null import sim_model_and_base
from calibration.effects import CATALOGUE
from calibration.hidden_effects import HiddenCase
from tests.sim_cache import recorded


def test_a_refit_to_fewer_harmonics_keeps_columns_and_parameters_together():
    """A friction profile refit with everything else in the model may come out with another
    number of harmonics, every column free. Its columns were replaced but the record of
    which were free was not, and reading its parameters then failed ("cannot assign 6 input
    values to the 8 output values"): on the WPI record once the thresholds changed."""
    model, base = sim_model_and_base()
    model.slope = 400.0
    rec, _ = recorded(HiddenCase((("position_friction", 3),), 0))
    w = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, None, Settings())
    eff = CATALOGUE["position_friction"]
    first, refit = (0.06, 4), (0.06, 3)     # (period m, harmonics)
    s = w._score(w._columns(eff, 3, first))
    assert not s["fixed_columns"]
    candidate = {"effect": eff.id, "joint": 3, "grid": first, "score": s, "delta_bic": 100.0, "heldout_gain": 0.5,
                 "gain_needed": 0.1, "params": eff.params(s["theta"], first, 3, w._baseline_terms(s["coef"], 3))}
    w._profile = lambda e, joint: (refit, w._score(w._columns(e, joint, refit)))   # the refit's choice
    w._accept(candidate, [candidate], w.detect())
    added = w.added[-1]
    assert added.grid == refit
    assert added.free.shape == (6,) and added.free.all()
    assert added.raw_cols.shape[2] == added.unfiltered.shape[2] == 6
    assert added.params["harmonics"] == 3
    assert np.isfinite([v for k, v in added.params.items() if isinstance(v, float)]).all()
