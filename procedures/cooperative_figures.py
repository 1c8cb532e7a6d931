"""The figures of `rig cooperative`, drawn from the run's log in memory or from its recording.

`rig plot` redraws them, for aborted runs up to where they stopped.

- `cooperative.png` (thesis Figure 7.11): the tool tips' x, y, z in the world frame,
  measured and planned; the tension against its set-point; the tension error F - F_d.
  Every panel shades the master's motion.
- `cooperative-tracking.png`: Cartesian tracking, one column per arm (slaves first):
  each tip measured against its plan on x, y, z, and the error.
- `cartesian_tracking()`: RMS and largest tip error per arm (mm), for the result and the
  report.

The plan (desired) tip of an arm is where the object's planned motion puts it (eq. 6.2-6.3,
with the live increments applied so far): the master is servoed to it; a slave's impedance
target is its plan moved along the object by its tension loop's offset (x_f), so a slave's
error along the object holds that stretch besides its tracking error.

What the recording holds for these (procedures/cooperative.py writes it): per control tick
`/cooperative/force_setpoint` (Float64, N), `/<arm>/measured_cp` and `/<arm>/setpoint_cp`
(positions in the world frame, m; rig.runs.recording.Recorder.point), the tension samples
`/loadcell/force` (force x, N; `/loadcell<k>/force` for element k > 0), and a
`cooperative_loop` metadata record: the loop's start on the run clock, the arms, the master
and the motion's window.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SETPOINT_TOPIC = "/cooperative/force_setpoint"
#: The model's tension estimate per tick (issue 47): element 0, then "...1", "...2".
TENSION_ESTIMATE_TOPIC = "/cooperative/tension_estimate"
#: ... from the arms' torques alone (before the object's stretch carries it), and its spread.
TENSION_TORQUES_TOPIC = "/cooperative/tension_estimate_torques"
TENSION_SPREAD_TOPIC = "/cooperative/tension_estimate_spread"
LOOP_METADATA = "cooperative_loop"
MIN_HALF_SPAN_MM = 1.0     # a position panel spans at least +-1 mm: encoder steps stay steps
MIN_HALF_SPAN_N = 0.1      # the error panel at least +-0.1 N


class FigureDataError(ValueError):
    """The recording holds nothing these figures can be drawn from (one line why)."""


def tension_topic(element: int) -> str:
    return "/loadcell/force" if element == 0 else f"/loadcell{element}/force"


def measured_cp_topic(arm: str) -> str:
    return f"/{arm}/measured_cp"


def setpoint_cp_topic(arm: str) -> str:
    return f"/{arm}/setpoint_cp"


@dataclass
class CooperativeTrace:
    """One value per control tick; times in s since the hold loop started."""

    title: str                       # names the run
    t: np.ndarray
    tension: np.ndarray              # ticks x elements, N (the newest sample at each tick)
    setpoint: np.ndarray             # N
    arms: list[str]
    master: str
    motion: tuple[float, float]      # the master's motion, s since the loop started
    x: dict[str, np.ndarray] = field(default_factory=dict)   # measured tips, world frame, m
    xd: dict[str, np.ndarray] = field(default_factory=dict)  # planned tips, world frame, m
    tolerance: float | None = None   # N, the run's --tolerance
    ceiling: float | None = None     # N, the run's --tension-ceiling
    stopped: str = ""                # how a run cut short ended ("aborted: ..."), drawn where it stopped
    elements: list[str] = field(default_factory=list)  # "PSM1-PSM2" per tension column, if known
    estimate: np.ndarray | None = None  # ticks x elements, N: the model's tension estimate, if recorded

    def element(self, k: int) -> str:
        return self.elements[k] if k < len(self.elements) else f"element {k + 1}"

    @property
    def slaves(self) -> list[str]:
        return [a for a in self.arms if a != self.master]


def loop_metadata(t_start: float, arms: list[str], master: str, motion_start: float, motion_end: float,
                  elements: list[tuple[str, str]]) -> dict:
    """The `cooperative_loop` metadata record (run-clock seconds)."""
    return {"t_start": repr(float(t_start)), "arms": ",".join(arms), "master": master,
            "motion_start": repr(float(motion_start)), "motion_end": repr(float(motion_end)),
            "elements": ";".join(f"{a}-{b}" for a, b in elements)}


def trace_from_log(log: dict, names: list[str], master: str, motion: tuple[float, float], title: str,
                   tolerance: float | None = None, ceiling: float | None = None,
                   elements: list[tuple[str, str]] = ()) -> CooperativeTrace:
    """From the procedure's in-memory log of a loop that ran to its end."""
    return CooperativeTrace(title, log["t"].copy(), log["tension"].copy(), log["setpoint"].copy(),
                            list(names), master, motion,
                            {a: log[f"{a}.x"].copy() for a in names},
                            {a: log[f"{a}.xd"].copy() for a in names}, tolerance, ceiling,
                            elements=[f"{a}-{b}" for a, b in elements],
                            estimate=log["tension_estimate"].copy() if "tension_estimate" in log else None)


def _parameter_values(start: dict) -> dict:
    params = start.get("parameters") if isinstance(start.get("parameters"), dict) else {}
    return {k: (v.get("value") if isinstance(v, dict) else v) for k, v in params.items()}


def _positions(rec, topic: str) -> np.ndarray:
    msgs = rec.messages.get(topic) or []
    return np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for _, m in msgs]).reshape(-1, 3)


def trace_from_recording(rec, title: str) -> CooperativeTrace:
    """From a cooperative run's recording (rig.runs.recording.read_recording, decoded), up to its
    last control tick. Recordings made before the tips were recorded give the tension
    panels only (no `x`, `xd`)."""
    start = rec.start or {}
    if start.get("procedure", "cooperative") != "cooperative":
        raise FigureDataError(f"{rec.path} is a {start.get('procedure')} run, not a cooperative one")
    samples = rec.messages.get(SETPOINT_TOPIC) or []
    if not samples:
        raise FigureDataError(f"{rec.path} holds no control-loop samples ({SETPOINT_TOPIC}): the run stopped "
                              "before it held the tension, or was a dry run")
    ticks = np.array([ns for ns, _ in samples], float) * 1e-9
    setpoint = np.array([m.data for _, m in samples], float)
    params = _parameter_values(start)
    config = start.get("config") if isinstance(start.get("config"), dict) else {}
    meta = rec.metadata.get(LOOP_METADATA)
    if meta:
        t_start = float(meta["t_start"])
        arms = [a for a in meta["arms"].split(",") if a]
        master = meta["master"]
        motion = (float(meta["motion_start"]) - t_start, float(meta["motion_end"]) - t_start)
        elements = [e for e in meta.get("elements", "").split(";") if e]
        n_elements = len(elements)
    else:  # recorded before the loop wrote its metadata: the loop's first tick is one period in
        rate = float((config.get("rig") or {}).get("rate") or 1000.0)
        t_start = ticks[0] - 1.0 / rate
        arms = list((config.get("object") or {}).get("arms") or
                    sorted({t.split("/")[1] for t in rec.schemas if t.endswith("/measured_js")}))
        master = arms[-1] if arms else ""
        settle, duration = float(params.get("settle", 0.0)), float(params.get("duration", 0.0))
        motion = (settle, settle + duration)
        n_elements = sum(1 for k in range(3) if tension_topic(k) in rec.schemas)
        elements = []
    n = len(ticks)
    x, xd = {}, {}
    for a in arms:
        measured, planned = _positions(rec, measured_cp_topic(a)), _positions(rec, setpoint_cp_topic(a))
        if len(measured) and len(planned):
            x[a], xd[a] = measured, planned
            n = min(n, len(measured), len(planned))
    tension = np.full((n, max(n_elements, 1)), np.nan)
    for k in range(n_elements):
        msgs = rec.messages.get(tension_topic(k)) or []
        if not msgs:
            continue
        ts = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for _, m in msgs])
        fs = np.array([m.wrench.force.x for _, m in msgs])
        order = np.argsort(ts, kind="stable")
        ts, fs = ts[order], fs[order]
        # the newest sample at each tick, as the loop saw it
        i = np.searchsorted(ts, ticks[:n], side="right") - 1
        tension[:, k] = np.where(i >= 0, fs[np.clip(i, 0, None)], np.nan)
    stop = rec.stop or {}
    status = stop.get("status") or "unfinished"
    # a failed run ran to its end: only a run cut short gets the line where it stopped
    stopped = "" if status in ("completed", "failed") else (
        f"{status}: {stop['error']}" if stop.get("error") else status)
    tolerance, ceiling = params.get("tolerance"), params.get("tension_ceiling")
    return CooperativeTrace(title, ticks[:n] - t_start, tension, setpoint[:n], arms, master, motion,
                            {a: v[:n] for a, v in x.items()}, {a: v[:n] for a, v in xd.items()},
                            float(tolerance) if tolerance is not None else None,
                            float(ceiling) if ceiling is not None else None, stopped, elements)


# ----------------------------------------------------------------------------- figures
def cartesian_tracking(trace: CooperativeTrace) -> dict:
    """Tip error |x - x_d| per arm (mm) from the motion's start to the end of the run
    (the whole hold if it stopped before the motion): RMS, largest, and the largest per
    world axis."""
    if not trace.x or not len(trace.t):
        return {}
    window = trace.t >= trace.motion[0]
    what = "from the motion's start"
    if not window.any():
        window = np.ones(len(trace.t), bool)
        what = "the whole hold (the run stopped before the motion)"
    arms = {}
    for a in trace.slaves + [trace.master]:
        if a not in trace.x:
            continue
        e = (trace.x[a] - trace.xd[a])[window] * 1e3
        norm = np.linalg.norm(e, axis=1)
        arms[a] = {"role": "master" if a == trace.master else "slave",
                   "rms_mm": float(np.sqrt(np.mean(norm ** 2))), "max_mm": float(np.max(norm)),
                   "max_axis_mm": {axis: float(np.max(np.abs(e[:, i]))) for i, axis in enumerate("xyz")}}
    return {"window": what, "window_s": [float(trace.t[window][0]), float(trace.t[window][-1])],
            "frame": "world", "arms": arms}


def tracking_lines(tracking: dict) -> list[str]:
    """The report's lines on Cartesian tracking."""
    if not tracking or not tracking.get("arms"):
        return []
    lines = [f"  Cartesian tracking, tool tip against its plan (world frame), {tracking['window']}:"]
    for a, v in tracking["arms"].items():
        ax = v["max_axis_mm"]
        lines.append(f"    {a} ({v['role']}): RMS {v['rms_mm']:.2f} mm, max {v['max_mm']:.2f} mm "
                     f"(largest |x| {ax['x']:.2f}, |y| {ax['y']:.2f}, |z| {ax['z']:.2f} mm)")
    if any(v["role"] == "slave" for v in tracking["arms"].values()):
        lines.append("    (a slave's error along the object includes the stretch its tension loop adds, x_f)")
    return lines


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _shade(ax, trace: CooperativeTrace, label: bool) -> None:
    ax.axvspan(trace.motion[0], trace.motion[1], color="0.9", zorder=0,
               label="master moving" if label else None)
    if trace.stopped and len(trace.t):
        ax.axvline(trace.t[-1], color="tab:red", lw=1.0, ls=":", label=f"run {trace.stopped}"[:90] if label else None)


def _span(ax, values: list[np.ndarray], half_min: float) -> None:
    """y limits around the data, at least +-half_min about their middle."""
    data = np.concatenate([np.ravel(v) for v in values if np.size(v)]) if values else np.array([])
    data = data[np.isfinite(data)]
    if not data.size:
        return
    lo, hi = float(data.min()), float(data.max())
    mid, half = 0.5 * (lo + hi), max(0.5 * (hi - lo) * 1.08, half_min)
    ax.set_ylim(mid - half, mid + half)


def _save(fig, path: Path) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


def draw_force_figure(trace: CooperativeTrace, path: Path) -> Path:
    """`force_figure` into a PNG file; returns its path."""
    return _save(force_figure(trace), path)


def draw_tracking_figure(trace: CooperativeTrace, path: Path) -> Path | None:
    """`tracking_figure` into a PNG file; None (nothing written) when the trace has no tips."""
    fig = tracking_figure(trace)
    return None if fig is None else _save(fig, path)


def force_figure(trace: CooperativeTrace):
    """Figure 7.11: tips x, y, z (world frame), tension and set-point, error F - F_d."""
    plt = _pyplot()
    t = trace.t
    has_tips = bool(trace.x)
    rows = (3 if has_tips else 0) + 2
    fig, axes = plt.subplots(rows, 1, figsize=(9, 2.1 * rows + 0.8), sharex=True, squeeze=False)
    axes = axes[:, 0]
    if has_tips:
        for i, axis in enumerate("xyz"):
            ax = axes[i]
            for a in trace.arms:
                if a not in trace.x:
                    continue
                role = "master" if a == trace.master else "slave"
                line, = ax.plot(t, 1e3 * trace.x[a][:, i], lw=1.2, label=f"{a} ({role}) measured")
                ax.plot(t, 1e3 * trace.xd[a][:, i], "--", lw=1.0, color=line.get_color(), alpha=0.8,
                        label=f"{a} ({role}) planned")
            _span(ax, [1e3 * trace.x[a][:, i] for a in trace.x] + [1e3 * trace.xd[a][:, i] for a in trace.xd],
                  MIN_HALF_SPAN_MM)
            ax.set_ylabel(f"tip {axis}, world frame [mm]")
            _shade(ax, trace, label=False)
        axes[0].legend(loc="best", fontsize=7, ncol=len(trace.arms))
    ax_f, ax_e = axes[-2], axes[-1]
    E = trace.tension.shape[1]
    for k in range(E):
        ax_f.plot(t, trace.tension[:, k], lw=1.0, label=f"tension {trace.element(k)}" if E > 1 else "tension F")
    if trace.estimate is not None:
        for k in range(trace.estimate.shape[1]):
            ax_f.plot(t, trace.estimate[:, k], ":", lw=1.0,
                      label=f"model estimate {trace.element(k)}" if E > 1 else "model estimate")
    ax_f.plot(t, trace.setpoint, "--", color="k", lw=1.0, label="set-point F_d")
    peak = float(np.nanmax(trace.tension)) if np.isfinite(trace.tension).any() else 0.0
    if trace.ceiling is not None and trace.ceiling <= 1.3 * max(peak, 0.0):
        # only when the tension came near it: a 15 N line would flatten a 5 N hold
        ax_f.axhline(trace.ceiling, color="tab:red", lw=0.9, ls="--", label=f"tension ceiling {trace.ceiling:g} N")
    ax_f.set_ylabel("tension [N]")
    _shade(ax_f, trace, label=True)
    ax_f.legend(loc="lower right", fontsize=7)
    error = trace.tension - trace.setpoint[:, None]
    for k in range(E):
        ax_e.plot(t, error[:, k], lw=0.9, label=trace.element(k) if E > 1 else None)
    ax_e.axhline(0.0, color="k", lw=0.6)
    # the axis fits the error from the motion's start on: the start-up's take-up (several
    # N) would otherwise flatten the tenths of a newton the hold is about
    fit = t >= trace.motion[0]
    if not fit.any():
        fit = np.ones(len(t), bool)
    finite = error[fit][np.isfinite(error[fit])]
    half = max(1.25 * float(np.max(np.abs(finite))) if finite.size else 0.0, MIN_HALF_SPAN_N)
    ax_e.set_ylim(-half, half)
    if trace.tolerance is not None and trace.tolerance <= half:
        for sign in (1, -1):
            ax_e.axhline(sign * trace.tolerance, color="tab:red", lw=0.8, ls=":",
                         label=f"tolerance +-{trace.tolerance:g} N" if sign > 0 else None)
    beyond = np.abs(error[~fit]) > half
    if beyond.any():
        ax_e.text(0.01, 0.04, "start-up beyond the axis (fitted from the motion's start)",
                  transform=ax_e.transAxes, fontsize=7, color="0.3",
                  bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.85})
    ax_e.set_ylabel("error F - F_d [N]")
    ax_e.set_xlabel("time since the hold started [s]")
    _shade(ax_e, trace, label=False)
    if ax_e.get_legend_handles_labels()[0]:
        ax_e.legend(loc="upper right", fontsize=7)
    fig.suptitle(f"{trace.title}\nCooperative force tracking (shaded: master moving)", fontsize=10)
    fig.tight_layout()
    return fig


def tracking_figure(trace: CooperativeTrace):
    """Cartesian tracking per arm: tip measured vs planned on x, y, z, and the error (mm).
    None when the trace has no tips."""
    if not trace.x:
        return None
    plt = _pyplot()
    arms = [a for a in trace.slaves + [trace.master] if a in trace.x]
    tracking = cartesian_tracking(trace)["arms"]
    fig, axes = plt.subplots(4, len(arms), figsize=(4.6 * len(arms) + 0.6, 9.5), sharex=True, squeeze=False)
    t = trace.t
    for j, a in enumerate(arms):
        x, xd = 1e3 * trace.x[a], 1e3 * trace.xd[a]
        v = tracking[a]
        axes[0, j].set_title(f"{a} ({v['role']}): RMS {v['rms_mm']:.2f} mm, max {v['max_mm']:.2f} mm\n"
                             f"from the motion's start", fontsize=9)
        for i, axis in enumerate("xyz"):
            ax = axes[i, j]
            ax.plot(t, x[:, i], lw=1.2, label="measured")
            ax.plot(t, xd[:, i], "--", lw=1.0, color="k", label="planned (desired)")
            _span(ax, [x[:, i], xd[:, i]], MIN_HALF_SPAN_MM)
            ax.set_ylabel(f"tip {axis}, world frame [mm]")
            _shade(ax, trace, label=(i == 0))
        axes[0, j].legend(loc="best", fontsize=7)
        ax = axes[3, j]
        e = x - xd
        for i, axis in enumerate("xyz"):
            ax.plot(t, e[:, i], lw=0.9, label=f"{axis}")
        ax.plot(t, np.linalg.norm(e, axis=1), color="k", lw=1.0, label="|error|")
        ax.axhline(0.0, color="k", lw=0.5)
        _span(ax, [e, np.linalg.norm(e, axis=1)], MIN_HALF_SPAN_MM)
        ax.set_ylabel("measured - planned [mm]")
        ax.set_xlabel("time since the hold started [s]")
        _shade(ax, trace, label=False)
        ax.legend(loc="best", fontsize=7, ncol=4)
    fig.suptitle(f"{trace.title}\nCartesian tracking: tool tips against their plan, world frame "
                 "(shaded: master moving)", fontsize=10)
    fig.tight_layout()
    return fig
