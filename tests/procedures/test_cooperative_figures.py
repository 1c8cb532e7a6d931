"""The cooperative figure (issue 36, point 5): every panel shaded, the frame named, an error
panel on which a 0.09 N error shows, encoder steps not blown up, Cartesian tracking drawn
and reported. On a made-up trace whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest

from procedures import cooperative_figures as cf

MOTION = (2.0, 7.0)


def _trace(**changes) -> cf.CooperativeTrace:
    t = np.arange(1, 9001) * 1e-3
    moving = (t >= MOTION[0]) & (t <= MOTION[1])
    setpoint = np.minimum(5.0, 5.0 * t)
    tension = (setpoint + 0.09 * np.sin(2 * np.pi * 1.0 * t) * moving)[:, None]
    tension[:300, 0] -= 2.0  # a start-up transient of 2 N
    xd = {"PSM1": np.tile([0.486, 1e-4, 0.0461], (len(t), 1)), "PSM2": np.tile([0.586, -1e-4, 0.0461], (len(t), 1))}
    x = {a: v.copy() for a, v in xd.items()}
    x["PSM1"][:, 1] += 1e-6 * np.round(np.sin(t))           # encoder steps of 1e-6 m on y
    x["PSM1"][moving, 2] += 0.0025                           # the slave's z 2.5 mm off its plan while moving
    x["PSM2"][moving, 0] -= 0.001                            # the master 1 mm behind on x
    trace = cf.CooperativeTrace("20260101T000000000000Z-cooperative (completed)", t, tension, setpoint,
                                ["PSM1", "PSM2"], "PSM2", MOTION, x, xd, tolerance=0.5, ceiling=15.0)
    for k, v in changes.items():
        setattr(trace, k, v)
    return trace


def _shaded(ax) -> bool:
    """A patch covering the motion window, full height (axvspan)."""
    for patch in ax.patches:
        box = patch.get_extents().transformed(ax.transData.inverted())
        if box.x0 == pytest.approx(MOTION[0], abs=1e-6) and box.x1 == pytest.approx(MOTION[1], abs=1e-6):
            return True
    return False


def test_force_figure_shades_every_panel_names_the_frame_and_shows_the_error():
    fig = cf.force_figure(_trace())
    axes = fig.axes
    assert len(axes) == 5
    assert all(_shaded(ax) for ax in axes)
    labels = [ax.get_ylabel() for ax in axes]
    assert labels[:3] == [f"tip {a}, world frame [mm]" for a in "xyz"]
    assert labels[3] == "tension [N]" and labels[4] == "error F - F_d [N]"
    assert axes[-1].get_xlabel() == "time since the hold started [s]"
    assert "20260101T000000000000Z-cooperative" in fig._suptitle.get_text()
    # a 0.09 N error fills most of its axis (fitted from the motion on, not to the 2 N start-up)
    lo, hi = axes[4].get_ylim()
    assert 0.09 <= hi <= 0.2 and -0.2 <= lo <= -0.09
    # y: steps of 1e-6 m on an axis of at least +-1 mm, not at full height
    lo, hi = axes[1].get_ylim()
    assert hi - lo >= 2.0 - 1e-9


def test_tracking_figure_and_numbers_per_arm():
    trace = _trace()
    tracking = cf.cartesian_tracking(trace)
    assert tracking["window"] == "from the motion's start" and tracking["frame"] == "world"
    slave, master = tracking["arms"]["PSM1"], tracking["arms"]["PSM2"]
    assert slave["role"] == "slave" and master["role"] == "master"
    assert slave["max_mm"] == pytest.approx(2.5, abs=1e-3) and slave["max_axis_mm"]["z"] == pytest.approx(2.5)
    window = trace.t >= MOTION[0]
    share = np.mean(trace.t[window] <= MOTION[1])  # the error is there only while moving
    assert slave["rms_mm"] == pytest.approx(2.5 * np.sqrt(share), rel=1e-3)
    assert master["max_mm"] == pytest.approx(1.0) and master["max_axis_mm"]["x"] == pytest.approx(1.0)
    lines = cf.tracking_lines(tracking)
    assert "PSM1 (slave): RMS" in lines[1] and "|z| 2.50 mm" in lines[1]
    fig = cf.tracking_figure(trace)
    assert len(fig.axes) == 8  # x, y, z and the error for each of two arms
    assert all(_shaded(ax) for ax in fig.axes)
    assert fig.axes[0].get_title().startswith("PSM1 (slave): RMS")  # slaves first
    assert fig.axes[-1].get_ylabel() == "measured - planned [mm]"


def test_a_run_cut_short_is_marked_where_it_stopped_and_a_trace_without_tips_draws_the_tension():
    trace = _trace(stopped="aborted: tension 15.2 N above the ceiling 15 N")
    fig = cf.force_figure(trace)
    assert any("run aborted: tension 15.2 N" in t for t in fig.axes[3].get_legend_handles_labels()[1])
    bare = _trace(x={}, xd={})
    assert len(cf.force_figure(bare).axes) == 2 and cf.tracking_figure(bare) is None
    assert cf.cartesian_tracking(bare) == {}
