"""A recorded run's joint arrays for `rig discrepancy` and `rig validate`, whole or as the pieces between pauses.

Its /<arm>/measured_js as q, dq, tau at a uniform rate, whole or as the continuous pieces
between the pauses in its stream.

Units: SI (rad, m, rad/s, m/s, N m, N, s, Hz).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def load_run_arrays(run_dir, arm: str, rate: float):
    """q, dq, tau (n, 3) of a run's measured_js at ``rate`` Hz."""
    from rig.runs.recording import read_recording
    from rig.runs.recorded_run import joint_arrays, resample, resolve_run

    d = resolve_run(str(run_dir))
    topic = f"/{arm}/measured_js"
    rec = read_recording(d / "run.mcap", topics=[topic])
    t, q, dq, tau = joint_arrays(rec, topic)
    _, table = resample(t, np.hstack((q[:, :3], dq[:, :3], tau[:, :3])), rate)
    return table[:, :3], table[:, 3:6], table[:, 6:9], f"{d / 'run.mcap'} {topic}"


#: A pause in a run's stream longer than this many periods of the workflow's filter cut-off
#: (0.5: 50 ms at 10 Hz) ends a piece. Bridged by interpolation, a shorter gap (a publisher
#: held up) changes nothing the filtered band sees; a longer one would be invented motion.
PAUSE_CUTOFF_PERIODS = 0.5


@dataclass
class RunRecord:
    """A run's q, dq, tau (n, 3) at ``rate`` Hz, its continuous pieces put end to end:
    ``breaks`` the sample indices where a piece after the first begins; ``dropped`` the pieces
    left out as too short for the workflow's filter ((start, stop) s from the first sample)."""

    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    source: str
    breaks: list[int]
    pieces: list[tuple[float, float]]
    dropped: list[tuple[float, float]]


def split_at_pauses(t: np.ndarray, max_gap: float) -> list[tuple[int, int]]:
    """(start, stop) index ranges of ``t`` (s, increasing) between pauses longer than ``max_gap`` s."""
    cuts = (np.flatnonzero(np.diff(t) > max_gap) + 1).tolist()
    edges = [0] + cuts + [len(t)]
    return list(zip(edges[:-1], edges[1:]))


def load_run_pieces(run_dir, arm: str, rate: float, settings) -> RunRecord:
    """A run's /<arm>/measured_js as continuous pieces, each resampled to ``rate`` Hz on its
    own grid (pauses in the stream longer than PAUSE_CUTOFF_PERIODS of the filter's cut-off
    end a piece); pieces too short for the workflow's filter are dropped and listed."""
    from calibration.discrepancy.preparation import MIN_PIECE_TRIMS
    from calibration.discrepancy.settings import DiscrepancyError
    from calibration.signals import settling_samples
    from rig.runs.recording import read_recording
    from rig.runs.recorded_run import joint_arrays, resample, resolve_run

    d = resolve_run(str(run_dir))
    topic = f"/{arm}/measured_js"
    rec = read_recording(d / "run.mcap", topics=[topic])
    t, q, dq, tau = joint_arrays(rec, topic)
    columns = np.hstack((q[:, :3], dq[:, :3], tau[:, :3]))
    shortest = MIN_PIECE_TRIMS * settling_samples(rate, settings.cutoff, settings.order)
    tables, breaks, pieces, dropped = [], [], [], []
    for a, b in split_at_pauses(t, PAUSE_CUTOFF_PERIODS / settings.cutoff):
        span = (float(t[a] - t[0]), float(t[b - 1] - t[0]))
        if b - a < 2 or (t[b - 1] - t[a]) * rate + 1 < shortest:
            dropped.append(span)
            continue
        if tables:
            breaks.append(sum(len(x) for x in tables))
        tables.append(resample(t[a:b], columns[a:b], rate)[1])
        pieces.append(span)
    source = f"{d / 'run.mcap'} {topic}"
    if not tables:
        raise DiscrepancyError(f"{source}: no stretch of the stream without a pause longer than "
                               f"{PAUSE_CUTOFF_PERIODS / settings.cutoff * 1e3:.0f} ms lasts "
                               f"{shortest / rate:.2f} s, the shortest the workflow's filter can use")
    table = np.vstack(tables)
    return RunRecord(table[:, :3], table[:, 3:6], table[:, 6:9], source, breaks, pieces, dropped)
