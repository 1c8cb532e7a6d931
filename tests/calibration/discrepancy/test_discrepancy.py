"""The discrepancy workflow on hidden-effect data from the simulated rig (issue 7).

Data are generated once per machine and code (tests/sim_cache.py) and the workflow run once
per session (a cache fixture); the workflow sees only the arrays.
The full sweep (every catalogue effect on every joint) is marked slow; bench/ prints its
confusion matrix.
"""

import numpy as np
import pytest

from calibration.discrepancy.residual_tests import heldout_r2, ljung_box
from calibration.discrepancy.settings import Settings
from calibration.discrepancy.workflow import Discrepancy
from calibration.discrepancy_null import reference_model, sim_model_and_base
from calibration.effect_model import EffectContext, dahl_state, gap_crossings, gap_torque
from calibration.effects import CATALOGUE, IDS, effects_torque, friction_profile
from calibration.hidden_effects import (CATALOGUE_CASES, REFERENCE_EXCITATION_PATH, HiddenCase,
                                        reference_excitation)
from rig.sim.world import SensorNoise
from tests.sim_cache import recorded


@pytest.fixture(scope="session")
def sim():
    return sim_model_and_base()


@pytest.fixture(scope="session")
def workflow(sim):
    cache = {}

    def run(effects, seed, mode="identified"):
        key = (tuple(effects), seed, mode)
        if key not in cache:
            model, base = sim
            model.slope = 400.0
            given = None
            if mode == "given_model":
                given, slope = reference_model(model, base, seed)
                model.slope = slope
            rec, truth = recorded(HiddenCase(tuple(effects), seed))
            w = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, given, Settings())
            cache[key] = (w.run(), w, truth)
        return cache[key]

    return run


def test_catalogue_is_fixed_and_versioned():
    assert IDS == ("stiction", "coulomb_asymmetry", "position_friction", "spring", "payload", "backlash",
                   "hysteresis", "time_delay", "torque_offset", "viscous_nonlinear")
    assert set(CATALOGUE_CASES) == set(IDS)


def test_sanity_checks_refuse_unphysical_parameters():
    st = CATALOGUE["stiction"]
    assert st.sanity({"dFs": -0.1, "Fs": 0.4, "Fc": 0.5, "vs": 0.01}, 3) is not None   # Fs < Fc
    assert st.sanity({"dFs": 0.2, "Fs": 0.7, "Fc": 0.5, "vs": 0.01}, 3) is None
    assert CATALOGUE["spring"].sanity({"k": -1.0, "q0": 0.0}, 1) is not None
    assert CATALOGUE["hysteresis"].sanity({"Fd": -0.1, "travel": 1e-3, "sigma0": -100}, 2) is not None


def test_coulomb_asymmetry_levels_are_those_of_its_torque():
    # The friction magnitude moving up is Fc + the effect's torque there, moving down Fc less
    # its torque there (the effort is -Fc + torque).
    eff = CATALOGUE["coulomb_asymmetry"]
    fc = 0.3
    for d in (0.2, -0.1):
        p = eff.params(np.array([d]), None, 3, {"Fc": fc})
        dq = np.zeros((2, 3))
        dq[:, 2] = [1.0, -1.0]
        up, down = eff.torque(p, 3, np.zeros((2, 3)), dq)[:, 2]
        assert p["Fc_pos"] == pytest.approx(fc + up) and p["Fc_neg"] == pytest.approx(fc - down)
    assert eff.sanity(eff.params(np.array([0.8]), None, 3, {"Fc": fc}), 3) is None
    assert eff.sanity(eff.params(np.array([-0.4]), None, 3, {"Fc": fc}), 3) is not None


def test_position_friction_profile_matches_its_columns_and_reads_older_entries():
    eff = CATALOGUE["position_friction"]
    t = np.linspace(0.0, 20.0, 400)
    q = np.column_stack([0.1 * np.sin(t)] * 2 + [0.15 + 0.05 * np.sin(t)])
    dq = np.gradient(q, 0.05, axis=0)
    ctx = EffectContext(q, dq, 200.0, 400.0)
    theta, g = np.array([0.02, -0.01, 0.03, 0.005]), (0.08, 2)
    cols = eff.columns(ctx, 3, g)[:, 2, :]
    p = eff.params(theta, g, 3, {"Fc": 0.5})
    assert p["harmonics"] == 2 and eff.linear_names_at(g) == ("a_sin1", "a_cos1", "a_sin2", "a_cos2")
    assert eff.n_params(g) == 5 and eff.n_params((0.08, 1)) == 3
    tq = eff.torque(p, 3, q, dq, rate=200.0, slope=400.0)
    np.testing.assert_allclose(tq[:, 2], cols @ theta, atol=1e-12)
    assert np.all(tq[:, :2] == 0)
    # A catalogue 1.1 entry (one ripple as amplitude and phase) and its one-harmonic form agree.
    legacy = {"amplitude": 0.05, "phase": 0.4, "period": 0.1, "Fc": 0.5}
    one = eff.params(np.array([0.05 * np.cos(0.4), 0.05 * np.sin(0.4)]), (0.1, 1), 3, {"Fc": 0.5})
    np.testing.assert_allclose(eff.torque(legacy, 3, q, dq), eff.torque(one, 3, q, dq), atol=1e-12)
    assert one["amplitude"] == pytest.approx(0.05, rel=1e-4) and one["phase"] == pytest.approx(0.4)
    # A profile that takes the friction level below zero is refused; a gentler one passes.
    assert eff.sanity(eff.params(np.array([0.0, 0.0, 0.7, 0.0]), (0.1, 2), 3, {"Fc": 0.5}), 3) is not None
    assert eff.sanity(eff.params(np.array([0.0, 0.0, 0.3, 0.0]), (0.1, 2), 3, {"Fc": 0.5}), 3) is None


def test_dahl_state_saturates_and_reverses():
    q = np.concatenate([np.linspace(0, 0.01, 50), np.linspace(0.01, 0.0, 50)])
    z = dahl_state(q, 0.001)
    assert z[49] == pytest.approx(1.0, abs=1e-3)
    assert z[-1] == pytest.approx(-1.0, abs=1e-3)


def test_play_crossing_time_and_contact_momentum():
    # The transmitted torque ramps through zero at r (N m/s): relative to the joint side the
    # motor travels r t^3 / (6 I) after the reversal, so it meets the far face of a play b at
    # t = (6 I b / r)^(1/3) with relative momentum I v = r t^2 / 2.
    rate, r, inertia, width = 1000.0, 2.0, 0.15, 0.01
    t = np.arange(-0.2, 1.0, 1.0 / rate)
    w, momentum = gap_crossings(r * t, inertia, rate, width)
    t_cross = (6 * inertia * width / r) ** (1 / 3)
    assert t[np.flatnonzero(w)[[0, -1]]] == pytest.approx([0.0, t_cross], abs=3e-3)
    k = np.flatnonzero(momentum)
    assert len(k) == 1 and momentum[k[0]] == pytest.approx(r * t_cross ** 2 / 2, rel=0.02)
    # The path's torque pays the viscous drag at the path's speed; the joint side, falling
    # behind, drags less, so it falls behind more slowly: the crossing takes longer.
    w_f, _ = gap_crossings(r * t, inertia, rate, width, dq=np.full_like(t, 0.2), friction=(0.0, 0.5))
    assert w_f.sum() > w.sum() + 3
    # The effort loses the transmitted torque while the play is open and gets the momentum
    # back at the contact: the change integrates to ~0 once the return has died out.
    d = gap_torque(r * t, np.zeros_like(t), inertia, None, rate, width, 0.0)
    assert d[w > 0] == pytest.approx(-r * t[w > 0])
    assert abs(d.sum() / rate) < 0.02 * r * t_cross ** 2 / 2


def test_catalogue_detection_needs_both_null_tests():
    # A joint the generic tests call white is structured only if its best sane candidate
    # beats the null's BIC gain and held-out gain thresholds together.
    from types import SimpleNamespace

    w = SimpleNamespace(th={"delta_bic": [40.0, 40.0, 40.0], "gain": [0.2, 0.2, 0.2]})
    det = [{"joint": j, "structured": False} for j in (1, 2, 3)]
    eligible = [{"effect": "backlash", "joint": 2, "delta_bic": 460.0, "heldout_gain": 0.9},
                {"effect": "backlash", "joint": 3, "delta_bic": 668.0, "heldout_gain": 0.15},
                {"effect": "spring", "joint": 1, "delta_bic": 30.0, "heldout_gain": 0.5}]
    Discrepancy._catalogue_detection(w, det, eligible)
    assert [d["structured"] for d in det] == [False, True, False]
    assert det[1]["catalogue"]["effect"] == "backlash"


def test_truth_carries_the_joint_side_velocity_the_encoder_misses_while_a_play_is_open():
    noise = SensorNoise().velocity_noise   # what the recorded velocity adds (rad/s, rad/s, m/s)
    null, truth = recorded(HiddenCase((), 0), n_samples=1200)
    gap = truth.joint_velocity - null.dq
    assert np.allclose(gap.std(0), noise, rtol=0.15)          # without a play: the noise only
    rec, truth = recorded(HiddenCase((("backlash", 1),), 0), n_samples=1200)
    gap = truth.joint_velocity[:, 0] - rec.dq[:, 0]
    open_play = np.abs(gap) > 6 * noise[0]
    assert np.abs(gap).max() > 0.05                                # the joint side coasts behind
    assert 0.005 < open_play.mean() < 0.2                          # only around a reversal
    assert (np.abs(truth.joint_velocity[:, 1:] - rec.dq[:, 1:]) < 6 * noise[1:]).all()   # no play there


def test_pitch_play_opens_only_on_a_balanced_pitch():
    # The simulated pitch axis carries 0.9-2.5 N m of gravity; a joint-2 backlash case balances
    # it (as the real PSM's is) so that the transmitted torque reverses; its twin does too.
    null, _ = recorded(HiddenCase((), 0), n_samples=2000)
    twin, _ = recorded(HiddenCase((("backlash", 2),), 0), n_samples=2000, twin=True)
    assert null.tau[:, 1].min() > 0.5
    assert twin.tau[:, 1].min() < -0.2 < 0.2 < twin.tau[:, 1].max()


def test_ljung_box_white_vs_coloured():
    rng = np.random.default_rng(0)
    white = rng.normal(size=400)
    coloured = np.convolve(white, np.ones(8) / 8, "same")
    assert ljung_box(white) < 30 < ljung_box(coloured)


def test_leave_one_out_flags_the_run_above_the_others():
    from calibration.discrepancy_null import leave_one_out

    def run(lb, r2):
        return {"ljung_box": lb, "library_r2": r2, "gain": [0.0] * 3, "delta_bic": [0.0] * 3}

    quiet = [run([20.0, 20.0, 20.0], [0.0, 0.0, 0.0]) for _ in range(5)]
    # Ljung-Box 30 on joint 2 is above 1.25 x 20 of the other runs; R^2 0.04 is under 0 + 0.05.
    doc = {"null_runs": {"identified": quiet + [run([20.0, 30.0, 20.0], [0.0, 0.0, 0.0])],
                         "given_model": quiet + [run([20.0, 20.0, 24.0], [0.0, 0.04, 0.0])]}}
    assert leave_one_out(doc) == {"identified": (1, 6), "given_model": (0, 6)}


def test_effort_lag_aligns_the_state_and_refuses_a_lead():
    from calibration.discrepancy.preparation import prepare
    from calibration.discrepancy.settings import DiscrepancyError

    rate, n = 200.0, 3000
    t = np.arange(n) / rate
    q = np.column_stack([np.sin(2 * np.pi * 0.5 * t)] * 3)
    dq = np.column_stack([np.pi * np.cos(2 * np.pi * 0.5 * t)] * 3)
    p = prepare(q, dq, np.zeros_like(q), rate, Settings(effort_lag=1e-3))
    # The state 1 ms before each sample (linear interpolation: within 1e-4 of the exact value).
    assert np.max(np.abs(p.q[1:, 0] - np.sin(2 * np.pi * 0.5 * (t[1:] - 1e-3)))) < 1e-4
    for bad in (-1e-3, 5e-3):
        with pytest.raises(DiscrepancyError, match="effort_lag"):
            prepare(q, dq, np.zeros_like(q), rate, Settings(effort_lag=bad))


def test_heldout_r2_sees_a_constant_residual():
    # An offset against a given model is a discrepancy: the share is of the mean square.
    rng = np.random.default_rng(1)
    F = rng.normal(size=(400, 3))
    r = 0.5 + 0.01 * rng.normal(size=400)
    assert heldout_r2(F[:200], r[:200], F[200:], r[200:]) > 0.99


def test_stuck_samples_do_not_leak_into_the_fit(workflow):
    # Joint 3 sticks at every reversal on the simulated rig; with the stuck raw samples masked
    # before filtering, the null held-out residual of the insertion joint is at the level its
    # effort noise leaves after the filter, not the stick-slip mismatch (several times that).
    res, w, _ = workflow([], 3)
    from rig.sim.world import SensorNoise
    sigma = SensorNoise().effort_noise[2] * np.sqrt(2 * w.p.cutoff / w.p.rate)
    assert res["baseline"]["heldout_rms"][2] < 2.5 * sigma


def test_added_effects_nonlinear_parameters_refit_with_the_final_model(workflow):
    # hysteresis@3 seed 2: the Dahl travel found with the first (soft) smooth sign came out
    # 16 % long and left 3x the floor on the held-out block; after the slope is re-chosen the
    # travel is refit with it.
    res, _, truth = workflow([("hysteresis", 3)], 2)
    e = res["effects"][0]
    t = truth.params[0]
    assert (e["name"], e["joint"]) == ("hysteresis", 3)
    assert e["params"]["travel"] == pytest.approx(t["size"] / t["stiffness"], rel=0.08)
    model, base = sim_model_and_base()
    twin, _ = recorded(HiddenCase((("hysteresis", 3),), 2), twin=True)
    floor = Discrepancy(model, base, twin.q, twin.dq, twin.tau, twin.rate, None, Settings()).heldout_rms()[2]
    assert res["final"]["heldout_rms"][2] < 1.4 * floor


def test_generator_follows_the_reference_excitation():
    # The reference runs' optimised excitation: the stored design, commanded through the PID
    # (recording starts after the 0.5 s settle).
    ft = reference_excitation()
    rec, _ = recorded(HiddenCase((), 7), n_samples=1000, excitation=ft)
    q_cmd = ft.sample(0.5 + np.arange(1000) / 200.0)[0]
    assert np.abs(rec.q - q_cmd).max() < 0.01
    assert np.ptp(rec.q, axis=0) == pytest.approx(np.ptp(q_cmd, axis=0), rel=0.05)


def test_reference_excitation_of_another_design_is_refused(tmp_path):
    import json
    doc = json.loads(REFERENCE_EXCITATION_PATH.read_text())
    doc["design"]["velocity_fraction"] = 0.85
    path = tmp_path / "exc.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="--design-reference"):
        reference_excitation(path)


# seed 1040 (16 s) is left out of the default run (under 10 min on two workers): seed 3 keeps the
# check there; -m slow runs it
@pytest.mark.parametrize("seed", [3, pytest.param(1040, marks=pytest.mark.slow)])
def test_reference_model_predicts_a_null_run_as_well_as_its_own_fit(sim, seed):
    # The "given_model" cases' model is identified beforehand on other runs (an optimised
    # excitation and a multi-sine). On a null run it must predict the held-out block about as
    # well as the thesis model identified on that run's own training block: a reference that
    # extrapolates worse leaves structure on null runs (false discoveries, and thresholds so
    # high that real effects go unseen). Seed 1040: a reference identified on one multi-sine
    # left 10x the run's own held-out RMS on joint 1 (its gravity's q1 dependence was traded
    # against other columns of that trajectory).
    model, base = sim
    rec, _ = recorded(HiddenCase((), seed))
    model.slope = 400.0
    own = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, None, Settings()).heldout_rms()
    given, slope = reference_model(model, base, seed)
    assert model.slope == slope
    ref = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, given, Settings()).heldout_rms()
    assert np.all(ref < 1.15 * own), (ref, own)


def test_stiction_on_the_insertion_joint_reaches_the_noise_floor(workflow):
    # Joint 3 sticks at every reversal and breaks away sharply: built from the filtered state
    # (filtered twice by the time it meets the effort) the inertial term missed the breakaway's
    # acceleration and the Stribeck fit left 5x the floor on the held-out block. Its inertial
    # term now comes from the measured velocity, which the training residual chooses.
    res, _, _ = workflow([("stiction", 3)], 0)
    assert [(e["name"], e["joint"]) for e in res["effects"]] == [("stiction", 3)], res["iterations"]
    assert res["inertia_source"][2] == "measured"
    model, base = sim_model_and_base()
    twin, _ = recorded(HiddenCase((("stiction", 3),), 0), twin=True)
    floor = Discrepancy(model, base, twin.q, twin.dq, twin.tau, twin.rate, None, Settings()).heldout_rms()[2]
    assert res["final"]["heldout_rms"][2] < 1.2 * floor
    assert res["final"]["heldout_rms"][2] < 0.5 * res["baseline"]["heldout_rms"][2]


def test_position_friction_ripple_is_one_harmonic_of_the_true_period(workflow):
    res, _, truth = workflow([("position_friction", 3)], 0)
    first = res["effects"][0]
    assert (first["name"], first["joint"]) == ("position_friction", 3), res["iterations"]
    assert first["params"]["harmonics"] == 1
    assert first["params"]["period"] == pytest.approx(truth.params[0]["period"], rel=0.05)


def test_position_friction_profile_of_two_harmonics_is_recovered(sim):
    # A null run of the rig whose insertion effort carries a friction level varying along the
    # stroke as two harmonics of 0.1 m (added to the recorded effort; the workflow sees only
    # the arrays): the information criterion picks two harmonics, not one and not four.
    model, base = sim
    model.slope = 400.0
    rec, _ = recorded(HiddenCase((), 7))
    truth = {"period": 0.1, "a_sin": [0.2, 0.0], "a_cos": [0.0, 0.15]}
    tau = rec.tau.copy()
    tau[:, 2] += np.tanh(200.0 * rec.dq[:, 2]) * friction_profile(truth, rec.q[:, 2])
    res = Discrepancy(model, base, rec.q, rec.dq, tau, rec.rate, None, Settings()).run()
    first = res["effects"][0]
    assert (first["name"], first["joint"]) == ("position_friction", 3), res["iterations"]
    p = first["params"]
    assert p["harmonics"] == 2 and p["period"] == pytest.approx(0.1, rel=0.05)
    # The profile over the stroke, up to a constant (the model's Coulomb level takes the mean).
    grid = np.linspace(rec.q[:, 2].min(), rec.q[:, 2].max(), 200)
    err = friction_profile(p, grid) - friction_profile(truth, grid)
    assert np.ptp(err) < 0.1 * np.ptp(friction_profile(truth, grid))
    assert res["final"]["heldout_rms"][2] < 0.5 * res["baseline"]["heldout_rms"][2]


def test_null_case_finds_nothing(workflow):
    res, _, _ = workflow([], 3)
    assert res["verdict"] == "none", res["iterations"]
    assert res["effects"] == []


# viscous_nonlinear@3 (40 s) and time_delay@3 (25 s) are left out of the default run (under 10 min
# on two workers): the time delay is named on joint 2 here and refit on joint 3 below, and the
# slow sweep (every effect on every joint) has both; -m slow runs them
@pytest.mark.parametrize("effect,joint", [("spring", 1), ("hysteresis", 3), ("time_delay", 2),
                                          pytest.param("viscous_nonlinear", 3, marks=pytest.mark.slow),
                                          ("stiction", 3), pytest.param("time_delay", 3, marks=pytest.mark.slow)])
def test_hidden_effect_is_named_on_its_joint(workflow, effect, joint):
    res, _, truth = workflow([(effect, joint)], 0)
    assert res["effects"], f"nothing found for {effect}@{joint}: {res['iterations']}"
    first = res["effects"][0]
    assert (first["name"], first["joint"]) == (effect, joint), res["iterations"]
    j = joint - 1
    assert first["heldout_rms_after"][j] < first["heldout_rms_before"][j]
    assert CATALOGUE[effect].sanity(first["params"], joint) is None


def test_time_delay_is_refit_where_the_lagged_equation_holds(workflow):
    # The effort recorded in the delay after a stuck interval is still the stuck interval's:
    # once a delay is named, the joint's stuck mask is extended by it and the delay refit.
    # Then the delay comes out near the truth and the gap closes to the rig's floor (its
    # twin without the delay), not the ~3x of the unmasked fit.
    res, w, truth = workflow([("time_delay", 3)], 0)
    e = res["effects"][0]
    assert e["params"]["delay"] == pytest.approx(truth.params[0]["size"], rel=0.2)
    assert w.mask_lag[2] >= int(np.ceil(truth.params[0]["size"] * w.p.rate)) - 1
    model, base = sim_model_and_base()
    twin, _ = recorded(HiddenCase((("time_delay", 3),), 0), twin=True)
    floor = Discrepancy(model, base, twin.q, twin.dq, twin.tau, twin.rate, None, Settings()).heldout_rms()[2]
    assert res["final"]["heldout_rms"][2] < 1.2 * floor
    assert res["final"]["heldout_rms"][2] < 0.5 * res["baseline"]["heldout_rms"][2]


def test_spring_stiffness_close_to_truth(workflow):
    res, _, truth = workflow([("spring", 1)], 0)
    k = res["effects"][0]["params"]["k"]
    assert k == pytest.approx(truth.params[0]["size"], rel=0.2)


def test_payload_against_an_earlier_model(workflow):
    res, _, truth = workflow([("payload", 3)], 0, "given_model")
    names = [(e["name"], e["joint"]) for e in res["effects"]]
    assert ("payload", 3) in names, res["iterations"]
    p = next(e for e in res["effects"] if e["name"] == "payload")["params"]
    assert p["mass"] == pytest.approx(truth.params[0]["size"], rel=0.25)


# 30 s: left out of the default run (under 10 min on two workers); the payload is found and its
# mass recovered on joint 3 by the two tests around it. -m slow runs it
@pytest.mark.slow
def test_payload_on_the_yaw_link_mass_from_its_inertia(workflow):
    # A mass on the yaw link loads joint 1 through its gravity (first moments) and its inertia
    # about the yaw axis; together they give the mass. The centre's component along the axis
    # changes no torque: it is reported as not determined.
    res, _, truth = workflow([("payload", 1)], 0, "given_model")
    first = res["effects"][0]
    assert (first["name"], first["joint"]) == ("payload", 1), res["iterations"]
    t = truth.params[0]
    p = first["params"]
    assert p["mass"] == pytest.approx(t["size"], rel=0.2)
    want = t["size"] * np.asarray(t["com"])
    got = np.asarray(p["first_moment"])
    assert np.abs(got[:2] - want[:2]).max() < 0.25 * np.abs(want).max()
    assert p["com_determined"][2] is False


def test_payload_point_mass_recovered_on_the_tool(workflow):
    res, _, truth = workflow([("payload", 3)], 0, "given_model")
    p = next(e for e in res["effects"] if e["name"] == "payload")["params"]
    t = truth.params[0]
    assert p["com_determined"] == [True, True, True]
    assert np.allclose(p["com"], t["com"], atol=0.01)


def test_two_effects_at_once(workflow):
    res, _, _ = workflow([("spring", 1), ("hysteresis", 3)], 0)
    found = {(e["name"], e["joint"]) for e in res["effects"]}
    assert {("spring", 1), ("hysteresis", 3)} <= found, res["iterations"]


def test_outside_catalogue_is_not_named(workflow):
    res, _, _ = workflow([("sinusoidal_disturbance", 1)], 0)
    # Structured (detected) but never explained by the nearest catalogue guess.
    assert res["verdict"] == "unexplained", res["iterations"]
    assert all(e["joint"] != 1 for e in res["effects"])
    # The closest catalogue effect is reported as evidence, with the test it failed.
    closest = {c["joint"]: c["candidate"] for c in res["closest_rejected"]}
    assert 1 in closest and closest[1] is not None
    c = closest[1]
    assert c["delta_bic"] <= c["delta_bic_needed"] or c["heldout_variance_removed"] < c["heldout_gain_needed"]
    from procedures.discrepancy import report
    text = report(res | {"data": {"source": "sim"}, "baseline_kind": "thesis model", "model": "m.json"})
    assert f"joint 1: closest catalogue effect {c['effect']}, not added" in text


def test_reidentification_with_a_given_model_is_validated_on_the_held_out_block(workflow, sim, monkeypatch):
    # Hysteresis is separable from the rigid-body/friction parameters, so the given model's
    # base parameters are re-identified with it; the effect's parameters then come from that
    # joint fit, and it is kept only if no joint predicts the held-out block >5 % worse.
    import calibration.discrepancy.refinement as D

    res, _, truth = workflow([("hysteresis", 3)], 0, "given_model")
    doc = res["reidentification"]
    assert doc["done"], doc
    assert np.all(np.array(doc["heldout_rms_reidentified"]) <= D.REIDENTIFY_TOLERANCE * np.array(
        doc["heldout_rms_fixed_model"]))
    assert res["final"]["heldout_rms"] == pytest.approx(doc["heldout_rms_reidentified"])
    fd = next(e for e in res["effects"] if e["name"] == "hysteresis")["params"]["Fd"]
    assert fd == pytest.approx(truth.params[0]["size"], rel=0.1)
    # A re-identification that generalises worse is refused: the given model with the effect stays.
    monkeypatch.setattr(D, "REIDENTIFY_TOLERANCE", 0.5)
    model, base = sim
    given, slope = reference_model(model, base, 0)
    rec, _ = recorded(HiddenCase((("hysteresis", 3),), 0))
    res2 = Discrepancy(model, base, rec.q, rec.dq, rec.tau, rec.rate, given, Settings()).run()
    assert not res2["reidentification"]["done"]
    assert "worse on joint(s)" in res2["reidentification"]["note"]
    assert res2["final"]["heldout_rms"] == pytest.approx(res2["reidentification"]["heldout_rms_fixed_model"])


def test_backlash_is_named_with_its_play_and_the_model_file_reproduces_its_torque(workflow, sim):
    # backlash@3 seed 1: the play's width, the unloaded fraction (~1: the drive transmits
    # nothing while the play is open) and the held-out gap against the twin's floor. Before
    # the contact's momentum was part of the component the crossings left 1.8x the floor.
    res, w, truth = workflow([("backlash", 3)], 1)
    e = res["effects"][0]
    assert (e["name"], e["joint"]) == ("backlash", 3), res["iterations"]
    p = e["params"]
    assert p["width"] == pytest.approx(truth.params[0]["size"], rel=0.35)
    assert 0.7 < p["unloaded_fraction"] < 1.3
    model, base = sim
    twin, _ = recorded(HiddenCase((("backlash", 3),), 1), twin=True)
    floor = Discrepancy(model, base, twin.q, twin.dq, twin.tau, twin.rate, None, Settings()).heldout_rms()[2]
    assert res["final"]["heldout_rms"][2] < 1.3 * floor
    assert res["final"]["heldout_rms"][2] < 0.5 * res["baseline"]["heldout_rms"][2]
    # The model file's entry gives the component's torque from (q, dq, ddq, the model's torque
    # and M_jj on the samples): the same as the fitted column times the unloaded fraction.
    from calibration.effects import EffectContext

    ctx = EffectContext(w.p.q, w.p.dq, w.p.rate, w.slope, w.tau_model_raw, w.W_raw, tuple(model.body_names),
                        np.array([p["inertia"]] * 3), w._mass_diag(), w.p.ddqf_all,
                        np.array([[p["Fc"], p["Fv"]]] * 3), np.array([p["stuck_velocity"]] * 3))
    col = CATALOGUE["backlash"].columns(ctx, 3, (p["width"], p["motor_fraction"]))[:, 2, 0]
    tq = effects_torque([e], w.p.q, w.p.dq, w.tau_model_raw, w.p.rate, w.slope, ddq=w.p.ddqf_all,
                        mass_diag=w._mass_diag())
    np.testing.assert_allclose(tq[:, 2], p["unloaded_fraction"] * col, atol=1e-12)
    assert np.all(tq[:, :2] == 0) and np.abs(col).max() > 0.1


def test_effects_torque_reproduces_the_fit(workflow):
    res, w, _ = workflow([("spring", 1), ("hysteresis", 3)], 0)
    e = next(e for e in res["effects"] if e["name"] == "spring")
    tq = effects_torque([e], w.p.q, w.p.dq)
    np.testing.assert_allclose(tq[:, 0], e["params"]["k"] * (w.p.q[:, 0] - (e["params"]["q0"] or 0.0)))
    assert np.all(tq[:, 1:] == 0)


@pytest.mark.slow
@pytest.mark.parametrize("effect", IDS)
@pytest.mark.parametrize("joint", [1, 2, 3])
def test_every_catalogue_effect_on_every_joint(workflow, effect, joint):
    mode = "given_model" if CATALOGUE[effect].in_rigid_body_model else "identified"
    res, _, _ = workflow([(effect, joint)], 0, mode)
    found = [(e["name"], e["joint"]) for e in res["effects"]]
    equivalent = {("coulomb_asymmetry", joint), ("torque_offset", joint)}
    want = equivalent if (effect, joint) in equivalent else {(effect, joint)}
    assert found and found[0] in want, (found, res["verdict"])


def test_augmented_model_file_as_the_simulated_plant_reproduces_the_recording(workflow, sim, tmp_path):
    # "Adds it to the model": the model file the procedure writes (physically consistent
    # standard parameters + the added effects) is a plant for the simulated rig. Replayed on
    # the case's trajectory with the same noise draws, its efforts match the recording to
    # well under a percent of the effects' size; the same parameters without the effects
    # miss by the effects.
    from rig.model.model_file import load_model, save_model
    from rig.model.plant_effects import HiddenEffects

    res, w, _ = workflow([("spring", 1), ("hysteresis", 3)], 0)
    model, _ = sim
    case = HiddenCase((("spring", 1), ("hysteresis", 3)), 0)
    rec, _ = recorded(case)
    pi, effects = w.augmented(res)
    assert res["standard_consistency"]["training_torque_change_rms"][0] < 1e-4
    m = load_model(save_model(tmp_path / "model.json", standard=pi, names=model.param_names(), slope=w.slope,
                              gravity=model.gravity, extra={"effects": effects}))
    params, eff = m.plant()
    rms = {}
    for label, plant in (("augmented", (params, eff)), ("without effects", (params, HiddenEffects()))):
        replay, _ = recorded(case, plant=plant)
        rms[label] = np.sqrt(((replay.tau - rec.tau) ** 2).mean(0))
    assert rms["without effects"][0] > 0.1 and rms["without effects"][2] > 0.3, rms
    assert np.all(rms["augmented"][[0, 2]] < 0.02 * rms["without effects"][[0, 2]]), rms
    assert np.all(rms["augmented"] < 0.005), rms


def test_inconsistent_fit_is_refitted_consistent_together_with_its_effects(workflow):
    # The least-squares rigid body of a hidden-effect case is not physically consistent. The
    # model as written is the best consistent one with the effects refitted beside it: on the
    # training block its weighted residual is below that of the consistent rigid body fitted
    # with the effects held at their unconstrained values, and the written effects are the
    # refit's (still near the truth).
    from calibration.estimators import Identification, check_physical, model_nominal

    res, w, truth = workflow([("spring", 1), ("hysteresis", 3)], 0)
    pi, entries = w.augmented(res)
    sc = res["standard_consistency"]
    assert sc["projected"] and sc["effects_refitted"]
    assert check_physical(pi, w.model)["all_pass"]
    r = w.Wb.shape[1]
    tr, rw = w.rows_tr, w.rw[w.rows_tr]
    D = w._joint_design()

    def sse(coef):
        return float(np.sum(((w.y[tr] - D[tr] @ coef) * rw) ** 2))

    coef_c, pi_c = w._consistent(model_nominal(w.model))
    assert np.allclose(pi_c, pi)
    effects_fixed = w.coef[r:]
    target = (w.y[tr] - D[tr, r:] @ effects_fixed) * rw
    alt = Identification(w.Wb[tr] * rw[:, None], target[:, None], w.base, w.model, nominal=model_nominal(w.model),
                         max_condition=np.inf).sdp(weighting="none", tol=1e-8)
    assert sse(coef_c) < sse(np.concatenate([alt.beta, effects_fixed]))
    assert sse(w.coef) <= sse(coef_c) <= 1.01 * sse(w.coef)
    assert np.allclose(sc["heldout_rms"], w.heldout_rms(D @ coef_c))
    assert sorted((e["name"], e["joint"]) for e in entries) == [("hysteresis", 3), ("spring", 1)]
    k = next(e["params"]["k"] for e in entries if e["name"] == "spring")
    assert k == pytest.approx(next(p["size"] for p in truth.params if p["effect"] == "spring"), rel=0.05)
    assert k != next(e["params"]["k"] for e in res["effects"] if e["name"] == "spring")


def test_thresholds_file_records_the_catalogue_it_was_calibrated_with(tmp_path):
    import json

    from calibration.discrepancy.settings import THRESHOLDS_PATH, load_thresholds
    from calibration.effects import CATALOGUE_VERSION

    thresholds, source = load_thresholds()
    assert json.loads(THRESHOLDS_PATH.read_text())["method"]["catalogue_version"] == CATALOGUE_VERSION
    assert "recalibrate" not in source
    doc = json.loads(THRESHOLDS_PATH.read_text())
    doc["method"]["catalogue_version"] = "1.1"
    old = tmp_path / "t.json"
    old.write_text(json.dumps(doc))
    again, source = load_thresholds(old)
    assert again == thresholds
    assert f"calibrated with catalogue 1.1, this is {CATALOGUE_VERSION}: recalibrate" in source
