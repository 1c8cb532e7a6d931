"""The load cell on USB serial: `LoadCell` (implements ForceSensor)."""

from __future__ import annotations

import threading
import time
from typing import Callable

from drivers.interfaces import ForceSample
from drivers.loadcell.errors import LoadCellDisconnected
from drivers.loadcell.force_calibration import LoadCellCalibration
from drivers.loadcell.frame_parser import FrameParser
from drivers.loadcell.protocol import REPLY, SAMPLE_FMT, T_SAMPLE, command_frame, decode_sample
from drivers.loadcell.streaming import _StreamingLoadCell


class LoadCell(_StreamingLoadCell):
    """Host driver for the Arduino load cell on a serial port (implements ForceSensor).

    `port` is an open pyserial `Serial` (or anything with read/write/in_waiting/timeout);
    the driver sets a short read timeout so its thread can stop, and never closes the port
    (whoever opened it closes it). On construction it identifies the device, sets
    `rate_hz` and, if `start`, starts streaming. `clock` gives host seconds for sample
    times; `on_sample(sample, host_rx_time)` is called from the reader thread for each
    new sample (recorders, benchmarks). `stale_timeout` (s): no sample for this long
    while streaming is a disconnect.
    """

    def __init__(self, port, calibration: LoadCellCalibration | None = None, *, rate_hz: int = 500,
                 stale_timeout: float = 0.05, clock: Callable[[], float] = time.monotonic,
                 on_sample: Callable[[ForceSample, float], None] | None = None,
                 buffer_size: int = 65536, start: bool = True, time_base=None) -> None:
        super().__init__(calibration, stale_timeout, clock, on_sample, buffer_size,
                         name=str(getattr(port, "port", None) or getattr(port, "name", None) or port),
                         time_base=time_base)
        self.port = port
        self.parser = FrameParser()
        try:
            port.timeout = 0.005
        except Exception:  # noqa: BLE001 - a port without a settable timeout still works
            pass
        self._thread = threading.Thread(target=self._reader, name=f"loadcell-{self.name}", daemon=True)
        self._thread.start()
        self._setup(rate_hz, start)

    def _send(self, ctype: int, payload: bytes) -> None:
        try:
            self.port.write(command_frame(ctype, payload))
        except Exception as exc:  # noqa: BLE001 - any port failure is a disconnect
            err = LoadCellDisconnected(f"load cell on {self.name}: write failed: {exc}")
            self._fail(err)
            raise err from exc

    def _reader(self) -> None:
        port, parser = self.port, self.parser
        while not self._stop.is_set():
            # Wait for a byte (up to the port timeout), then take everything the port holds
            # at `rx`: every byte that had arrived by then is parsed before the stream's age
            # is judged at `rx`, so a reader that could not run for a while (the process
            # busy, the machine loaded) finds the samples waiting, not a silent cell.
            try:
                first = port.read(1) if port.in_waiting == 0 else b""
                rx = self.clock()
                n = port.in_waiting
                data = None if first is None else first + (port.read(n) if n else b"")
            except Exception as exc:  # noqa: BLE001 - pyserial raises SerialException/OSError/TypeError on hangup
                self._lost_port(f"port read failed: {exc}")
                return
            if data is None:
                self._lost_port("port returned EOF")
                return
            if data:
                for frame in parser.feed(data):
                    if frame.type == T_SAMPLE and len(frame.payload) == SAMPLE_FMT.size:
                        self._on_raw_sample(decode_sample(frame.payload), rx)
                    elif frame.type & REPLY:
                        self._on_reply(frame.type, frame.payload)
                with self._lock:
                    self._copy_parser_stats()
            self._last_poll = rx
            self._check_stale(rx)
            # the clock first, then the port: empty now means every byte written before that
            # time has been read above, and parsed (`caught_up`)
            now = self.clock()
            try:
                if port.in_waiting == 0 and now > self._caught_up:
                    self._caught_up = now
                    self.time_base.notify()
            except Exception:  # noqa: BLE001 - a port that went away: the next read says so
                pass

    def caught_up(self, t: float) -> bool:
        """See `_StreamingLoadCell.caught_up`; when not yet, wakes the reader from its wait
        for a byte (pyserial's cancel_read), so that it looks again at once."""
        if super().caught_up(t):
            return True
        cancel = getattr(getattr(self, "port", None), "cancel_read", None)  # (set after the base)
        if cancel is not None:
            try:
                cancel()
            except Exception:  # noqa: BLE001 - a port that went away: the reader says so
                pass
        return False

    def _copy_parser_stats(self) -> None:
        st, p, sq = self._stats, self.parser, self._seq
        st.frames_ok, st.crc_errors, st.truncated = p.frames, p.crc_errors, p.truncated
        st.bad_length, st.resyncs, st.bytes_discarded = p.bad_length, p.resyncs, p.bytes_discarded
        st.gaps, st.lost, st.out_of_order, st.restarts = sq.gaps, sq.lost, sq.out_of_order, sq.restarts

    def _lost_port(self, why: str) -> None:
        with self._lock:
            self.parser.flush()
            self._copy_parser_stats()
        self._fail(LoadCellDisconnected(f"load cell on {self.name} disconnected: {why}"))
