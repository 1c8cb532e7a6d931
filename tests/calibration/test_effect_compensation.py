"""A model file's added effects fed forward by the controllers (issue 7: the augmented model
is one "the controllers ... can use"): `calibration.effects.EffectCompensation` in
`rig.control.controllers.FeedforwardModel`, and what it buys an impedance-controlled arm."""

import numpy as np

from calibration.effects import EffectCompensation, effects_torque
from rig.control.controllers import follow_path
from rig.model.model_file import load_model, save_model
from rig.model.psm_dynamics import PSMDynamics, PSMParameters

EFFECTS = [
    {"name": "position_friction", "joint": 3,
     "params": {"period": 0.03, "harmonics": 2, "a_sin": [0.4, 0.05], "a_cos": [0.0, -0.1]}},
    {"name": "spring", "joint": 3, "params": {"k": 30.0, "q0": 0.08}},
    {"name": "hysteresis", "joint": 3, "params": {"Fd": 0.5, "travel": 0.0008}},
    {"name": "torque_offset", "joint": 1, "params": {"offset": 0.12}},
    {"name": "spring", "joint": 2, "params": {"k": 1.0, "q0": 0.0}},
    {"name": "stiction", "joint": 2, "params": {"dFs": 0.1, "Fs": 0.18, "Fc": 0.08, "vs": 0.02}},
    {"name": "viscous_nonlinear", "joint": 1, "params": {"c": 0.5, "exponent": 2.0}},
]


def test_step_by_step_torques_equal_the_batch_evaluation():
    # The controller's one-step evaluation (with its own Dahl state) is the catalogue's
    # torque on the whole path; entries it cannot feed forward are listed with a reason.
    t = np.arange(0, 3, 1e-3)
    q = np.column_stack([0.3 * np.sin(2 * t), 0.2 * np.sin(1.3 * t), 0.12 + 0.04 * np.sin(2.9 * t)])
    dq = np.gradient(q, 1e-3, axis=0)
    skipped = [{"name": "backlash", "joint": 1, "params": {"width": 0.01}},
               {"name": "time_delay", "joint": 2, "params": {"delay": 0.01}},
               {"name": "payload", "joint": 3, "params": {"mass": 0.1}, "applied_to": "standard_parameters"}]
    comp = EffectCompensation(EFFECTS + skipped, 400.0)
    online = np.array([comp(q[k], dq[k]) for k in range(len(t))])
    batch = effects_torque(EFFECTS, q, dq, slope=400.0)
    np.testing.assert_allclose(online, batch, atol=1e-12)
    assert np.ptp(online[:, 2]) > 1.0
    assert [(s["name"], s["joint"]) for s in comp.skipped] == [("backlash", 1), ("time_delay", 2), ("payload", 3)]
    assert all(s["reason"] for s in comp.skipped)
    assert not EffectCompensation(skipped, 400.0)


def test_impedance_with_the_model_files_effects_follows_a_path_on_that_plant(tmp_path):
    # One arm whose plant is the model file (rigid body + the effects) follows a Cartesian
    # path under impedance control; fed the file's effects, the tip stays far closer to it.
    path = save_model(tmp_path / "model.json", standard=PSMParameters().standard_vector(),
                      names=PSMDynamics.param_names(), slope=400.0, gravity=[0, 0, -9.81],
                      extra={"effects": EFFECTS})
    m = load_model(path)
    params, plant_effects = m.plant()
    dyn = m.dynamics()

    def track(feed_effects):
        return follow_path((params, plant_effects), dyn,
                           EffectCompensation(m.effects, m.slope) if feed_effects else None)

    fed, blind = track(True), track(False)
    assert blind > 3e-3                # the effects push the tip millimetres off the path ...
    assert fed < 0.1 * blind           # ... which feeding them forward removes
    assert fed < 5e-4
