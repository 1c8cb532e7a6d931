"""rig link-lengths end to end on the simulated rig, against the simulated truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rig.runs.recording import read_recording
from tests.procedures._cli import run_cli


def test_link_lengths_cli_meets_targets_against_truth():
    code, r, err = run_cli("link-lengths", "--json", "--seed", "3")
    assert code == 0, err
    assert r["status"] == "completed"
    errors = r["truth"]["errors"]
    for name, e in errors["lengths"].items():
        assert abs(e) < 0.3e-3, f"{name} off by {e * 1e3:.3f} mm"
    for axis, deg in errors["axes_deg"].items():
        assert deg < 0.1, f"{axis} direction off by {deg:.3f} deg"
    # every Table 4.1 quantity and implied DH length carries an uncertainty
    assert set(r["lengths"]) == {"l1", "l2", "l12", "l2'", "l3", "l4"}
    assert all(v["std"] > 0 for v in r["lengths"].values())
    assert abs(r["dh"]["a4"]["value"] - 0.516) < 0.3e-3
    # both the plain and the bias-compensated fits are reported
    assert {"plain", "bias_compensated"} <= set(r["fits"]["z2_pitch"])
    run_dir = Path(r["run_dir"])
    assert json.loads((run_dir / "result.json").read_text())["lengths"] == r["lengths"]
    assert (run_dir / "link_lengths.png").stat().st_size > 10_000
    topics = read_recording(run_dir / "run.mcap").counts()
    assert topics.get("/PSM1/measured_js", 0) > 10_000
    assert topics.get("/mocap/PSM1_pitch_back/pose", 0) > 500
    assert "table 4.1" in err.lower()


def test_too_little_range_of_motion_is_refused():
    code, r, err = run_cli("link-lengths", "--json", "--q1-range", "0.05", "--q2-range", "0.05",
                           "--q3-stroke", "0.02", "--passes", "1")
    assert code != 0
    assert "too little range of motion" in err
    assert "yaw axis" in err  # names what is missing


def test_steps_lists_without_moving(tmp_path):
    code, _, _ = run_cli("link-lengths", "--steps")
    assert code == 0
    assert not (tmp_path / "logs").exists()


def test_fit_refuses_an_occluded_body():
    from calibration.fit_error import FitError
    from procedures.link_lengths_fit import fit_fixed_axis
    from calibration.captures import Capture

    n = 200
    ang = np.linspace(-1, 1, n)
    R = np.stack([np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) for a in ang])
    p = np.zeros((n, 3))
    R_occ, p_occ = R.copy(), p.copy()
    R_occ[: int(0.8 * n)] = np.nan
    p_occ[: int(0.8 * n)] = np.nan
    cap = Capture("q1 sweep", np.arange(n) / 120.0, {"yaw": (R_occ, p_occ)}, {},
                  {"PSM1": np.column_stack([ang, 0 * ang, 0 * ang])})
    try:
        fit_fixed_axis(cap, np.eye(4), "yaw", 1, "PSM1", "yaw axis z1")
    except FitError as exc:
        assert "occluded" in str(exc) and "yaw" in str(exc)
    else:
        raise AssertionError("an 80 % occluded body was fitted")
