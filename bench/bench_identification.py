"""Issue 5 benchmarks: the dynamic identification mathematics, timed and checked.

    python bench/bench_identification.py [--model psm|reference] [--starts 4] [--skip-real] [--quick]

0. Unit-test-sized timings (the tests check these results, the bench their speed): base
   parameters of the model, first call, target < 0.5 s (tests/calibration/
   test_cal_psm_identification.py); base parameters of the 92-parameter reference arm,
   target < 0.5 s (test_cal_base_params.py); the short excitation optimisation of
   test_cal_excitation.py (reference arm, 1 start, 8 SLSQP iterations), target < 4 s.
   `--quick` runs only these.
1. Excitation: optimise a Fourier trajectory (5 harmonics, 0.13 Hz, 30 s, 6001 samples at
   200 Hz) for the base regressor's condition number; target < 120 s. With
   `--model reference` this is the design of test_cal_excitation.py's slow test, which
   checks the condition number and leaves the time to this figure.
2. Simulated recording on that trajectory: true parameters, measurement noise on dq and
   tau, then the whole fit - processing (zero-phase filter, differentiation, trimming),
   regressor, base parameters, OLS, WLS, SDP with checks; target < 10 s for 6000 x 3.
3. Validation on a second, unseen trajectory: per-joint relative torque error of the SDP
   model against the noiseless truth; target <= 5 %.
4. Real data (shared/data/wpi-psm/one_results.csv, joints 1-3, PSM model only): per-joint
   relative error on a held-out last quarter, reported against the published 7-DOF figures.

Uses rig.model.psm_dynamics.PSMDynamics when it is importable (``--model psm``, the default),
otherwise the reference arm of calibration.reference_arm; the table says which.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _table import print_table  # noqa: E402

from calibration.base_params import base_parameters_of  # noqa: E402
from calibration.datasets import JointData, load_csv, processed, split_blocks  # noqa: E402
from calibration.estimators import Identification, model_nominal, validation_errors  # noqa: E402
from calibration.excitation import ExcitationDesigner, FourierTrajectory, rest_basis  # noqa: E402

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "wpi-psm" / "one_results.csv"
PUBLISHED = np.array([0.093, 0.178, 0.191])


def load_model(which: str):
    if which == "psm":
        try:
            from rig.model.psm_dynamics import PSMDynamics
            from rig.model.psm_kinematics import DQ_MAX, Q_MAX, Q_MIN
            return "PSMDynamics (rig.model.psm_dynamics)", PSMDynamics(), Q_MIN, Q_MAX, DQ_MAX
        except ImportError as e:
            print(f"rig.model.psm_dynamics not importable ({e}); using the reference arm", file=sys.stderr)
    from calibration.reference_arm import ReferenceArm
    arm = ReferenceArm(seed=0)
    return "ReferenceArm (calibration.reference_arm)", arm, arm.q_min, arm.q_max, arm.dq_max


def true_params(model) -> np.ndarray:
    return np.asarray(model.true_params() if hasattr(model, "true_params") else model_nominal(model))


def second_trajectory(q_min, q_max, dq_max, seed=7) -> FourierTrajectory:
    """An unseen validation trajectory: random rest-to-rest coefficients at 0.16 Hz, 70 % of the limits."""
    rng = np.random.default_rng(seed)
    Z = rest_basis(0.16, 30.0)
    c = rng.normal(size=(3, Z.shape[1])) @ Z.T
    tr = FourierTrajectory(0.16, c[:, :5], c[:, 5:], np.zeros(3), 30.0)
    q, dq, _ = tr.sample(tr.times(200.0))
    half, mid = 0.5 * (q_max - q_min), 0.5 * (q_max + q_min)
    s = np.minimum(0.7 * half / np.abs(q - q.mean(0)).max(0), 0.7 * dq_max / np.abs(dq).max(0))
    return FourierTrajectory(0.16, c[:, :5] * s[:, None], c[:, 5:] * s[:, None], mid - s * q.mean(0), 30.0)


def record(model, traj: FourierTrajectory, pi, rng, rate=200.0, dq_noise=0.01, tau_noise=(0.02, 0.02, 0.1)):
    """A simulated recording: q exact, dq and tau with white noise (rad/s, N m / N)."""
    t = traj.times(rate)
    q, dq, ddq = traj.sample(t)
    tau = (model.regressor_batch(q, dq, ddq) @ pi).reshape(-1, 3)
    return JointData(t, q, dq + dq_noise * rng.normal(size=dq.shape),
                     tau + np.asarray(tau_noise) * rng.normal(size=tau.shape), rate, "simulated"), tau


def unit_test_timings() -> list[tuple[str, str, str, bool]]:
    """Rows for the reference-arm computations the calibration unit tests make (and check)."""
    from calibration.reference_arm import ReferenceArm
    arm = ReferenceArm(seed=0)
    t0 = time.perf_counter()
    base = base_parameters_of(arm.regressor_batch, arm.param_layout, arm.q_min, arm.q_max, arm.dq_max)
    t_base = time.perf_counter() - t0
    d = ExcitationDesigner(arm.regressor_batch, base.independent, arm.q_min, arm.q_max, arm.dq_max,
                           ddq_max=np.array([6.0, 6.0, 1.5]), duration=30.0, n_objective=150, n_constraint=600)
    t0 = time.perf_counter()
    d.optimise(n_starts=1, seed=1, maxiter=8)
    t_short = time.perf_counter() - t0
    return [(f"base parameters of ReferenceArm ({arm.param_layout.n_params} standard) [s]", f"{t_base:.3f}",
             "< 0.5", t_base < 0.5),
            ("short excitation optimisation, ReferenceArm (1 start, 8 iterations) [s]", f"{t_short:.2f}", "< 4",
             t_short < 4.0)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", choices=["psm", "reference"], default="psm")
    ap.add_argument("--starts", type=int, default=4, help="seeded starts of the excitation optimisation")
    ap.add_argument("--skip-real", action="store_true", help="skip the real-data figures")
    ap.add_argument("--quick", action="store_true", help="only the unit-test-sized timings (section 0)")
    a = ap.parse_args()
    label, model, q_min, q_max, dq_max = load_model(a.model)
    print(f"model: {label}")
    rows = []
    rng = np.random.default_rng(0)
    pi_true = true_params(model)
    nominal = pi_true * rng.uniform(0.8, 1.2, pi_true.size)  # a nominal model 20 % off

    # 0. Timings of the unit tests' computations (first call, as a test makes it).
    t0 = time.perf_counter()
    base = base_parameters_of(model.regressor_batch, model, q_min, q_max, dq_max)
    t_base = time.perf_counter() - t0
    rows += [(f"base parameters of {label.split()[0]}, first call [s]", f"{t_base:.3f}", "< 0.5", t_base < 0.5)]
    rows += unit_test_timings()
    if a.quick:
        return 0 if print_table(f"Unit-test-sized timings ({label})", rows) else 1

    # 1. Excitation.
    designer = ExcitationDesigner(model.regressor_batch, base.independent, q_min, q_max, dq_max)
    exc = designer.optimise(n_starts=a.starts, seed=0, time_budget=100.0,
                            progress=lambda k, n, c: print(f"  excitation start {k}/{n}: best cond {c:.1f}",
                                                           file=sys.stderr))
    rows += [("excitation optimisation time [s]", f"{exc.seconds:.1f}", "< 120", exc.seconds < 120),
             (f"excitation cond, objective ({exc.n_objective_samples} samples)", f"{exc.condition_objective:.1f}",
              "report (thesis 128.7)", True),
             (f"excitation cond, full ({exc.n_full_samples} samples)", f"{exc.condition_full:.1f}", "< 300",
              exc.condition_full < 300),
             ("excitation max limit use (q, dq)", f"{max(max(v) for v in exc.limit_use.values()):.3f}", "<= 1",
              max(max(v) for v in exc.limit_use.values()) <= 1.0)]

    # 2. The whole fit on a simulated recording of that trajectory.
    data, _ = record(model, exc.trajectory, pi_true, rng)
    t0 = time.perf_counter()
    proc = processed(data)
    t_proc = time.perf_counter() - t0
    base_fit = base_parameters_of(model.regressor_batch, model, q_min, q_max, dq_max)
    ident = Identification.from_model(model, proc, base_fit, nominal=nominal)
    t_setup = time.perf_counter() - t0
    ols, wls, wls_tm = ident.ols(), ident.wls(), ident.wls("tau_max")
    sdp = ident.sdp()
    t_fit = time.perf_counter() - t0
    rows += [(f"whole fit, {data.n_samples} x 3 samples [s]", f"{t_fit:.2f}", "< 10", t_fit < 10),
             ("  of which processing / regressor+base / SDP [s]",
              f"{t_proc:.2f} / {t_setup - t_proc:.2f} / {sdp.info['seconds']:.2f}", "report", True),
             ("base parameters", f"{base_fit.n_base} of {base_fit.n_standard}", "report", True),
             ("LS cond (column-normalised W_b)", f"{ols.condition:.1f}", "report (thesis 159.7)", True),
             ("WLS cond, residual-std weights (default)", f"{wls.condition:.1f}", "report", True),
             ("WLS cond, 1/tau_max weights (thesis)", f"{wls_tm.condition:.1f}", "report (thesis 298.0)", True),
             ("residual norm OLS / WLS / SDP",
              f"{ols.residual_norm:.2f} / {wls.residual_norm:.2f} / {sdp.residual_norm:.2f}", "report", True),
             ("SDP checks (pseudo-inertia, masses, friction, M(q))", "all pass" if sdp.checks["all_pass"] else "FAIL",
              "all pass", sdp.checks["all_pass"]),
             ("SDP solver status / iterations", f"{sdp.info['status']} / {sdp.info['iterations']}", "optimal",
              sdp.info["status"] == "optimal"),
             ("OLS realizable (physically consistent)", str(ols.checks["realizable"]["pass"]), "report", True)]

    # 3. Validation on an unseen trajectory against the noiseless truth.
    val_traj = second_trajectory(q_min, q_max, dq_max)
    val_raw, _ = record(model, val_traj, pi_true, np.random.default_rng(1))
    val = processed(val_raw)
    Wv = base_fit.regressor(model.regressor_batch(val.q, val.dq, val.ddq))
    truth = (model.regressor_batch(val.q, val.dq, val.ddq) @ pi_true).reshape(-1, 3)
    for fit in (ols, wls, sdp):
        e = validation_errors(truth, fit.predict(Wv, 3))["relative_error"]
        ok = bool(np.all(e <= 0.05)) if fit.method == "sdp" else True
        rows.append((f"validation rel. error {fit.method.upper()} (j1, j2, j3)",
                     " / ".join(f"{x:.4f}" for x in e), "<= 0.05" if fit.method == "sdp" else "report", ok))

    # 4. Real data.
    if not a.skip_real and label.startswith("PSMDynamics") and REAL.exists():
        t0 = time.perf_counter()
        real = processed(load_csv(REAL, rate=200.0, joints=3))
        train, held = split_blocks(real, 0.25)
        ident_r = Identification.from_model(model, train, base_fit)
        fits = [ident_r.ols(), ident_r.wls(), ident_r.sdp()]
        Wh = base_fit.regressor(model.regressor_batch(held.q, held.dq, held.ddq))
        for fit in fits:
            e = validation_errors(held.tau, fit.predict(Wh, 3))["relative_error"]
            rows.append((f"real data held-out rel. error {fit.method.upper()}", " / ".join(f"{x:.3f}" for x in e),
                         "report (7-DOF: .093/.178/.191)", True))
        rows.append(("real data SDP checks", "all pass" if fits[2].checks["all_pass"] else "FAIL", "all pass",
                     fits[2].checks["all_pass"]))
        rows.append(("real data fit time [s]", f"{time.perf_counter() - t0:.2f}", "report", True))

    ok = print_table(f"Dynamic identification ({label})", rows)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
