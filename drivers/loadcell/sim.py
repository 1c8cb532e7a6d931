"""The load cell of the simulated rig on simulated time: `SimForceSensor`.

Why not `LoadCell` over `FakeLoadCellFirmware` here: the firmware fake runs its own thread
paced by the wall clock, while a procedure on the simulated rig runs many times faster
than real time; samples would then not line up with the world's steps and runs would not
be deterministic. (`rig sim`, which is paced to the wall clock, does serve that pair on a
pty.) This sensor keeps the same device physics and the same bytes, synchronously: on each
sample instant of the rig clock it asks the firmware's own `LoadCellDeviceModel` for a
conversion of `world.tension(element)` (its noise, drift, ADC clipping and saturation
flag), frames it exactly as the firmware does (`sample_frame`), parses it back with the
host driver's `FrameParser` and converts counts to newtons with a `LoadCellCalibration`
(by default the exact two-point calibration of the model, as `rig loadcell-calibrate`
would find it). Sample times are the rig clock's (s); forces in N, tension positive.
"""

from __future__ import annotations

from collections import deque

from drivers.interfaces import ForceSample
from drivers.loadcell.device_model import LoadCellDeviceModel
from drivers.loadcell.force_calibration import STANDARD_GRAVITY, LoadCellCalibration
from drivers.loadcell.frame_parser import FrameParser
from drivers.loadcell.protocol import SAMPLE_FMT, T_SAMPLE, decode_sample, sample_frame


class SimForceSensor:
    """ForceSensor fake on the simulated rig clock (see the module docstring).

    world, clock: the simulated rig and its `SimClock`; element: object element index;
    rate: Hz; noise: N rms; drift: N/s; seed: the ADC noise stream;
    calibration: counts -> N (default: exact for the model).
    """

    def __init__(self, world, clock, element: int = 0, rate: float = 500.0, noise: float = 0.02,
                 drift: float = 0.0, seed: int = 0, calibration: LoadCellCalibration | None = None,
                 max_buffer: int = 1_000_000):
        self.world = world
        self.clock = clock
        self.element = element
        self.name = ""   # no port: a line about it names its element
        self.model = LoadCellDeviceModel(lambda: world.tension(element), clock.now, noise=noise,
                                         drift=drift, rate_hz=int(round(rate)), seed=seed)
        self.model.streaming = True
        if calibration is None:
            m = self.model
            calibration = LoadCellCalibration.from_two_points(
                0.0, m.true_counts(0.0), 1.0, m.true_counts(STANDARD_GRAVITY), device="simulated")
        self.calibration = calibration
        self.parser = FrameParser()
        self.period = 1.0 / rate
        self._next = clock.now()
        self._buffer: deque[ForceSample] = deque(maxlen=max_buffer)
        self._recent_counts: deque[int] = deque(maxlen=64)
        self._latest: ForceSample | None = None
        self.saturated = 0
        self._closed = False
        clock.add_listener(self._on_tick)

    def _on_tick(self, t: float) -> None:
        if t + 1e-9 < self._next:
            return
        self._next += self.period * max(1, int((t + 1e-9 - self._next) // self.period) + 1)
        raw, _ = self.model.tick()
        for frame in self.parser.feed(sample_frame(raw)):
            if frame.type != T_SAMPLE or len(frame.payload) != SAMPLE_FMT.size:
                continue
            s = decode_sample(frame.payload)
            if s.saturated:
                self.saturated += 1
            self._recent_counts.append(s.counts)
            sample = ForceSample(t=t, force=self.calibration.newtons(s.counts), raw=s.counts, seq=s.seq)
            self._buffer.append(sample)
            self._latest = sample

    def read(self) -> ForceSample:
        """The newest sample (raises RuntimeError before the first sample instant)."""
        if self._latest is None:
            raise RuntimeError("simulated load cell: no sample yet; tick the clock first")
        return self._latest

    def stream_age(self) -> float:
        """Seconds of rig time since the newest sample (inf before the first)."""
        return float("inf") if self._latest is None else self.clock.now() - self._latest.t

    def samples(self) -> list[ForceSample]:
        """Every sample since the last call, oldest first."""
        out = list(self._buffer)
        self._buffer.clear()
        return out

    def tare(self) -> None:
        """Zero on the mean of the last (up to 64) samples, as the firmware's TARE does."""
        if not self._recent_counts:
            raise RuntimeError("simulated load cell: cannot tare before the first sample")
        mean = sum(self._recent_counts) / len(self._recent_counts)
        self.calibration = self.calibration.with_tare(mean)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            remove = getattr(self.clock, "remove_listener", None)
            if remove is not None:
                remove(self._on_tick)
