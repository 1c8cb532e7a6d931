"""Time-series figures of every stream a run recorded (what `rig plot` draws for any run).

One PNG per group of topics, against the run clock (s):

- `plot-<arm>-joints.png`: the JointState topics of one arm (measured_js, servo_jp,
  servo_jf, ...): a row per quantity (position, velocity, effort), a column per joint;
  joint 3 of a PSM is prismatic (m, m/s, N), the others revolute (rad, rad/s, N m).
- `plot-<group>-poses[-<frame>].png`: the PoseStamped positions (mm) of one group in one
  frame, x, y, z (`/PSM1/measured_cp` with `/PSM1/setpoint_cp`; the mocap bodies
  `/mocap/<body>/pose`; their markers `/mocap/markers/...`).
- `plot-forces.png`: the WrenchStamped topics, one panel per topic (the load-cell
  tension is force x of `/loadcell/force`), torques on a panel of their own.
- `plot-signals[-k].png`: every other topic (Float64 set-points and timings, Twist
  commands, any other type), one panel per topic, at most eight panels a figure.

Where a run did not end (aborted, unfinished) a dotted red line marks its last sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rig.runs.recording import Recording
from rig.runs.topic_tables import TopicError, TopicTable, topic_table

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"

#: what a signal topic holds, for its axis label
SIGNAL_LABELS = {
    "/cooperative/force_setpoint": "tension set-point [N]",
    "/cooperative/loop_time_us": "controller step [us]",
    "/cooperative/x_f": "first slave's offset x_f [m]",
    "/psm/cmd_force": "tension increment [N]",
    "/psm/cmd_vel": "increment [m; rad]",
}
QUANTITIES = (("position", "rad", "m"), ("velocity", "rad/s", "m/s"), ("effort", "N m", "N"))
MAX_POINTS = 20000       # per line: longer series are thinned by a stride (the shape stays)
PANELS_PER_FIGURE = 8
MIN_HALF_SPAN_POSITION = 1e-3  # rad or m: a joint position panel spans at least +-1 mrad, +-1 mm
MIN_HALF_SPAN_MM = 1.0         # a Cartesian position panel at least +-1 mm


def _thin(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    step = max(1, len(t) // MAX_POINTS)
    return t[::step], y[::step]


def _at_least(ax, half: float) -> None:
    """Widen the y axis to at least +-half about its middle: encoder steps stay steps."""
    lo, hi = ax.get_ylim()
    if hi - lo < 2 * half:
        mid = 0.5 * (lo + hi)
        ax.set_ylim(mid - half, mid + half)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _parent(topic: str) -> str:
    return topic.rsplit("/", 1)[0] or "/"


def _first(topic: str) -> str:
    parts = [p for p in topic.split("/") if p]
    return parts[0] if parts else "root"


def _pose_group(topic: str) -> str:
    """`PSM1` for /PSM1/measured_cp, `mocap` for /mocap/<body>/pose, `mocap/markers` for
    /mocap/markers/<body>/<marker>: the bodies and their markers in figures of their own."""
    parts = [p for p in topic.split("/") if p]
    return "/".join(parts[:2]) if len(parts) >= 4 else (parts[0] if parts else "root")


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in name).strip("-") or "root"


class _Figures:
    def __init__(self, out_dir: Path, title: str, stop_t: float | None, stop_label: str):
        self.out_dir, self.title = Path(out_dir), title
        self.stop_t, self.stop_label = stop_t, stop_label
        self.written: list[Path] = []

    def mark(self, ax, label: bool) -> None:
        if self.stop_t is not None:
            ax.axvline(self.stop_t, color="tab:red", ls=":", lw=1.0,
                       label=self.stop_label[:90] if label else None)

    def save(self, fig, name: str, what: str) -> None:
        fig.suptitle(f"{self.title}\n{what}", fontsize=10)
        fig.tight_layout()
        path = self.out_dir / name
        fig.savefig(path, dpi=100)
        _pyplot().close(fig)
        self.written.append(path)


def _joint_unit(arm_group: str, j: int, quantity: int) -> str:
    revolute, prismatic = QUANTITIES[quantity][1], QUANTITIES[quantity][2]
    is_psm = _first(arm_group).upper().startswith("PSM") and arm_group.count("/") == 1
    return prismatic if (is_psm and j == 2) else revolute


def _joints(figs: _Figures, group: str, tables: list[TopicTable]) -> None:
    plt = _pyplot()
    rows = []
    for qi, (quantity, _, _) in enumerate(QUANTITIES):
        width = max((sum(c.startswith(f"{quantity}_") for c in tb.columns) for tb in tables), default=0)
        if width:
            rows.append((qi, quantity, width))
    if not rows:
        return
    n = max(w for _, _, w in rows)
    fig, axes = plt.subplots(len(rows), n, figsize=(2.9 * n + 0.8, 2.3 * len(rows) + 1.0), sharex=True,
                             squeeze=False)
    for r, (qi, quantity, _) in enumerate(rows):
        for j in range(n):
            ax = axes[r, j]
            for tb in tables:
                name = f"{quantity}_{j + 1}"
                if tb.has(name):
                    style = "-" if tb.topic.endswith("measured_js") else "--"
                    ax.plot(*_thin(tb.t, tb.column(name)), style, lw=0.9, label=tb.topic[len(group) + 1:])
            if quantity == "position":
                _at_least(ax, MIN_HALF_SPAN_POSITION)
            ax.set_ylabel(f"{quantity} [{_joint_unit(group, j, qi)}]")
            if r == 0:
                ax.set_title(f"joint {j + 1}", fontsize=9)
            if r == len(rows) - 1:
                ax.set_xlabel("time on the run clock [s]")
            figs.mark(ax, label=(r == 0 and j == 0))
    for r in range(len(rows)):
        for j in range(n):
            if axes[r, j].get_legend_handles_labels()[0]:
                axes[r, j].legend(fontsize=7, loc="best")
                break
    figs.save(fig, f"plot-{_safe(group)}-joints.png", f"{group}: joint states")


def _poses(figs: _Figures, first: str, frame: str, tables: list[TopicTable]) -> None:
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for i, axis in enumerate("xyz"):
        ax = axes[i]
        for k, tb in enumerate(tables):
            label = tb.topic[len(first) + 2:] or tb.topic
            planned = any(w in tb.topic for w in ("setpoint", "servo", "goal"))
            ax.plot(*_thin(tb.t, 1e3 * tb.column(f"position_{axis}")), lw=1.0, ls="--" if planned else "-",
                    marker="o" if len(tb.t) < 50 else None, ms=3, label=label if k < 12 else None)
        _at_least(ax, MIN_HALF_SPAN_MM)
        ax.set_ylabel(f"{axis}{', ' + frame + ' frame' if frame else ''} [mm]")
        figs.mark(ax, label=(i == 0))
    axes[0].legend(fontsize=7, loc="best", ncol=2)
    axes[-1].set_xlabel("time on the run clock [s]")
    more = f" ({len(tables)} topics, 12 named)" if len(tables) > 12 else ""
    suffix = f"-{_safe(frame)}" if frame else ""
    figs.save(fig, f"plot-{_safe(first)}-poses{suffix}.png",
              f"/{first}: positions{' in the ' + frame + ' frame' if frame else ''}{more}")


def _panels(figs: _Figures, tables: list[TopicTable], name: str, what: str, draw) -> None:
    """`draw(ax, table)` for each table, PANELS_PER_FIGURE panels a figure."""
    plt = _pyplot()
    pages = [tables[i:i + PANELS_PER_FIGURE] for i in range(0, len(tables), PANELS_PER_FIGURE)]
    for p, page in enumerate(pages):
        fig, axes = plt.subplots(len(page), 1, figsize=(9, 2.1 * len(page) + 1.0), sharex=True, squeeze=False)
        for k, tb in enumerate(page):
            ax = axes[k, 0]
            draw(ax, tb)
            ax.set_title(tb.topic, fontsize=9, loc="left")
            figs.mark(ax, label=(k == 0))
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7, loc="best", ncol=3)
        axes[-1, 0].set_xlabel("time on the run clock [s]")
        suffix = f"-{p + 1}" if len(pages) > 1 else ""
        figs.save(fig, f"{name}{suffix}.png", what + (f" ({p + 1} of {len(pages)})" if len(pages) > 1 else ""))


def _draw_wrench(ax, tb: TopicTable) -> None:
    forces = [c for c in ("force_x", "force_y", "force_z") if tb.has(c) and np.any(tb.column(c))]
    torques = [c for c in ("torque_x", "torque_y", "torque_z") if tb.has(c) and np.any(tb.column(c))]
    for c in forces or ["force_x"]:
        ax.plot(*_thin(tb.t, tb.column(c)), lw=0.9, label=c.replace("_", " ") + " [N]")
    if torques:
        twin = ax.twinx()
        for c in torques:
            twin.plot(*_thin(tb.t, tb.column(c)), "--", lw=0.9, label=c.replace("_", " "))
        twin.set_ylabel("torque [N m]")
    tension = tb.topic.startswith("/loadcell") and forces in ([], ["force_x"])
    ax.set_ylabel("tension (force x) [N]" if tension else "force [N]")


def _draw_signal(ax, tb: TopicTable) -> None:
    for c in tb.columns[:8]:
        ax.plot(*_thin(tb.t, tb.column(c)), lw=0.9, label=c if len(tb.columns) > 1 else None)
    ax.set_ylabel(SIGNAL_LABELS.get(tb.topic, tb.columns[0] if len(tb.columns) == 1 else "value"), fontsize=8)


def stream_figures(rec: Recording, out_dir: Path, title: str, stopped: str = "") -> tuple[list[Path], list[str]]:
    """Draw every recorded stream of `rec` into `out_dir`; returns (files written, topics
    left out with why). `stopped`: how a run cut short ended, marked at its last sample."""
    tables: list[TopicTable] = []
    skipped: list[str] = []
    for topic in sorted(rec.schemas):
        try:
            tables.append(topic_table(rec, topic))
        except TopicError as exc:
            skipped.append(str(exc))
    last = max((float(tb.t[-1]) for tb in tables), default=None)
    figs = _Figures(out_dir, title, last if stopped else None, f"run {stopped}")
    joints: dict[str, list[TopicTable]] = {}
    poses: dict[tuple[str, str], list[TopicTable]] = {}
    wrenches, signals = [], []
    for tb in tables:
        if tb.schema == JOINT_STATE:
            joints.setdefault(_parent(tb.topic), []).append(tb)
        elif tb.schema == POSE_STAMPED:
            poses.setdefault((_pose_group(tb.topic), tb.frame_id), []).append(tb)
        elif tb.schema == WRENCH_STAMPED:
            wrenches.append(tb)
        else:
            signals.append(tb)
    for group, group_tables in joints.items():
        _joints(figs, group, group_tables)
    for (first, frame), group_tables in poses.items():
        _poses(figs, first, frame, group_tables)
    if wrenches:
        _panels(figs, wrenches, "plot-forces", "forces (WrenchStamped)", _draw_wrench)
    if signals:
        _panels(figs, signals, "plot-signals", "set-points, timings and commands", _draw_signal)
    return figs.written, skipped
