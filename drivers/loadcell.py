"""Arduino load cell on USB serial: wire protocol, host driver, calibration, firmware fake.

The protocol is specified in `drivers/LOADCELL_PROTOCOL.md`; this module follows it byte
for byte and the sketch in `drivers/firmware/loadcell/loadcell.ino` implements it on the
Arduino. Layers, bottom up:

- pure protocol functions: `crc16_ccitt_false`, `encode_frame`, payload packers, and
  `FrameParser`, a streaming parser that resynchronises on garbage and counts what it
  rejects;
- `SequenceTracker` (gaps, out-of-order, device restarts) and `ClockMapper` (device
  micros() -> host seconds, with u32 wraparound and crystal drift);
- `LoadCellCalibration`: counts -> newtons from two known masses, plus a tare offset;
- `LoadCell`: the host driver. It is given an open pyserial-like port, runs a reader
  thread, and implements `drivers.interfaces.ForceSensor`;
- `FakeLoadCellFirmware`: the sketch's behaviour on a pseudo-terminal, fed by a tension
  source (N), with noise, drift, saturation, corrupt frames and unplugging.

Units: force in newtons (N, tension positive), time in seconds on the host clock unless
a name ends in `_us` (device microseconds), raw ADC values in counts.
"""

from __future__ import annotations

import abc

import json
import math
import os
import queue
import random
import select
import struct
import threading
import time
import tty
from collections import deque
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

from drivers.interfaces import ForceSample
from rig.faults import DeviceFault, rate_of, silence_text, starved_text

# --------------------------------------------------------------------------- protocol

PROTOCOL_VERSION = 1
#: baud of the serial link: the firmware's LOADCELL_BAUD (firmware/loadcell/loadcell.ino), the one
#: place the host side takes it from (rig.toml's [loadcell] baudrate default). 250000 is exact on a
#: 16 MHz AVR (115200 is 2 % off there) and carries a 500 Hz stream at 38 % of the line.
BAUDRATE = 250000

#: s, longest wait for a command's reply. The firmware answers within a few ms; the margin is
#: for the host: a starved 2-core machine (two CPU burners, a procedure and `rig sim` serving
#: the pty) delivered a SET_RATE reply more than 0.5 s late (bench/bench_kill.py, 2 of 112 runs)
COMMAND_TIMEOUT = 1.5
FIRMWARE_VERSION = (1, 0, 0)
SYNC = b"\xa5\x5a"
MAX_PAYLOAD = 16  # bytes; a larger LEN byte can only be corruption
FRAME_OVERHEAD = 6  # sync (2) + LEN (1) + TYPE (1) + CRC (2)

# frame types (LOADCELL_PROTOCOL.md, "Frame types")
T_SAMPLE = 0x01
CMD_IDENTIFY = 0x10
CMD_TARE = 0x11
CMD_SET_RATE = 0x12
CMD_START = 0x13
CMD_STOP = 0x14
CMD_STATUS = 0x15
REPLY = 0x80  # a reply's type is the command's type | REPLY
T_ERROR = 0xFF

KNOWN_TYPES = frozenset({T_SAMPLE, T_ERROR, *(c | r for c in range(0x10, 0x16) for r in (0, REPLY))})
COMMAND_NAMES = {CMD_IDENTIFY: "IDENTIFY", CMD_TARE: "TARE", CMD_SET_RATE: "SET_RATE",
                 CMD_START: "START", CMD_STOP: "STOP", CMD_STATUS: "STATUS"}

# error codes carried by a T_ERROR reply
ERR_UNKNOWN_COMMAND = 0x01
ERR_BAD_CRC = 0x02
ERR_BAD_ARGUMENT = 0x03
ERR_BAD_LENGTH = 0x04
ERR_BUSY = 0x05
ERR_INCOMPLETE = 0x06
ERROR_NAMES = {ERR_UNKNOWN_COMMAND: "unknown command", ERR_BAD_CRC: "bad CRC",
               ERR_BAD_ARGUMENT: "bad argument", ERR_BAD_LENGTH: "bad length",
               ERR_BUSY: "busy", ERR_INCOMPLETE: "incomplete frame"}

ADC_HX711 = 0
ADC_INA = 1
ADC_NAMES = {ADC_HX711: "HX711 24-bit", ADC_INA: "INA + 10-bit ADC x16 oversampled"}

SAMPLE_SATURATED = 0x01  # sample flags bit 0: the ADC was at a limit
STATUS_STREAMING = 0x01
STATUS_TARE_BUSY = 0x02
STATUS_SATURATED = 0x04

# payload layouts, all little-endian (LOADCELL_PROTOCOL.md, "Payloads")
SAMPLE_FMT = struct.Struct("<IIiB")  # seq u32, t_us u32, counts i32, flags u8
IDENTITY_FMT = struct.Struct("<BBBBBH")  # protocol, fw major, minor, patch, adc kind, max rate Hz
TARE_CMD_FMT = struct.Struct("<B")  # conversions to average
TARE_REPLY_FMT = struct.Struct("<iB")  # mean counts, conversions averaged
RATE_FMT = struct.Struct("<H")  # Hz
STATUS_FMT = struct.Struct("<HBHH")  # rate Hz, status flags, rx errors, tx dropped
ERROR_FMT = struct.Struct("<BB")  # offending type byte, error code

COMMAND_PAYLOAD_LEN = {CMD_IDENTIFY: 0, CMD_TARE: 1, CMD_SET_RATE: 2, CMD_START: 0,
                       CMD_STOP: 0, CMD_STATUS: 0}


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16_ccitt_false(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0 (check 0x29B1)."""
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]
    return crc


def encode_frame(ftype: int, payload: bytes = b"") -> bytes:
    """One frame: A5 5A | LEN | TYPE | PAYLOAD | CRC16 (LE) over LEN, TYPE and PAYLOAD."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = bytes((len(payload), ftype)) + payload
    return SYNC + body + struct.pack("<H", crc16_ccitt_false(body))


@dataclass(frozen=True)
class Frame:
    type: int
    payload: bytes


@dataclass(frozen=True)
class RawSample:
    """A sample as the device sent it: sequence number, device time (us), ADC counts."""

    seq: int
    t_us: int
    counts: int
    flags: int = 0

    @property
    def saturated(self) -> bool:
        return bool(self.flags & SAMPLE_SATURATED)


@dataclass(frozen=True)
class Identity:
    protocol: int
    firmware: tuple[int, int, int]
    adc: int
    max_rate_hz: int


@dataclass(frozen=True)
class Status:
    rate_hz: int
    flags: int
    rx_errors: int
    tx_dropped: int

    @property
    def streaming(self) -> bool:
        return bool(self.flags & STATUS_STREAMING)


def sample_frame(s: RawSample) -> bytes:
    return encode_frame(T_SAMPLE, SAMPLE_FMT.pack(s.seq & 0xFFFFFFFF, s.t_us & 0xFFFFFFFF, s.counts, s.flags))


def decode_sample(payload: bytes) -> RawSample:
    return RawSample(*SAMPLE_FMT.unpack(payload))


def identity_payload(i: Identity) -> bytes:
    return IDENTITY_FMT.pack(i.protocol, *i.firmware, i.adc, i.max_rate_hz)


def decode_identity(payload: bytes) -> Identity:
    p, a, b, c, adc, rate = IDENTITY_FMT.unpack(payload)
    return Identity(p, (a, b, c), adc, rate)


def status_payload(s: Status) -> bytes:
    return STATUS_FMT.pack(s.rate_hz, s.flags, min(s.rx_errors, 0xFFFF), min(s.tx_dropped, 0xFFFF))


def decode_status(payload: bytes) -> Status:
    return Status(*STATUS_FMT.unpack(payload))


def command_frame(ctype: int, payload: bytes = b"") -> bytes:
    return encode_frame(ctype, payload)


def error_frame(offending_type: int, code: int) -> bytes:
    return encode_frame(T_ERROR, ERROR_FMT.pack(offending_type & 0xFF, code))


class FrameParser:
    """Splits a byte stream into CRC-checked frames and counts what it had to reject.

    Counters (events, not bytes, except `bytes_discarded`):
      frames       valid frames returned
      crc_errors   complete frames whose CRC did not match
      truncated    frames cut short: a frame header (sync, sane LEN, known TYPE) starts
                   inside them (a corrupted LEN byte that makes a frame swallow the next
                   one looks the same on the wire)
      bad_length   LEN byte above MAX_PAYLOAD (cannot be a frame; skipped)
      resyncs      times bytes were skipped to find the next sync that belonged to no
                   counted frame (garbage, line noise, a partial frame at start-up)
    A frame whose CRC passes but which holds a plausible header inside is accepted only
    when the next frame starts right after it (the two following bytes are a sync), since
    a 16-bit CRC passes a cut frame spliced with its successor once in 65536; such a frame
    waits for those two bytes.
    `on_reject(kind, type_byte)` is called for every rejected frame, so the firmware fake
    can answer a bad command with an error reply.
    """

    def __init__(self, max_payload: int = MAX_PAYLOAD,
                 on_reject: Callable[[str, int], None] | None = None) -> None:
        self.max_payload = max_payload
        self.on_reject = on_reject
        self._buf = bytearray()
        self.frames = 0
        self.crc_errors = 0
        self.truncated = 0
        self.bad_length = 0
        self.resyncs = 0
        self.bytes_discarded = 0
        self._skipping = False  # inside a run of garbage (one resync however it is fed)

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def _skip(self, n: int) -> None:
        del self._buf[:n]
        self.bytes_discarded += n

    def _skip_garbage(self, n: int) -> None:
        if not self._skipping:
            self.resyncs += 1
            self._skipping = True
        self._skip(n)

    def _reject(self, kind: str, ftype: int) -> None:
        if self.on_reject is not None:
            self.on_reject(kind, ftype)

    def _header_at(self, j: int) -> bool | None:
        """Whether a plausible frame header (sync, LEN <= max, known TYPE) is at offset j;
        None if its bytes have not arrived yet."""
        buf = self._buf
        if len(buf) < j + 4:
            return None
        return buf[j + 2] <= self.max_payload and buf[j + 3] in KNOWN_TYPES

    def _inner_header(self, end: int) -> bool | None:
        """Whether a plausible header starts inside the frame that ends at `end` (and, if
        one does, whether the two bytes after the frame have arrived: None until they have)."""
        buf = self._buf
        j = buf.find(SYNC, 1, end)
        while j > 0:
            plausible = self._header_at(j)
            if plausible is None or plausible:
                break
            j = buf.find(SYNC, j + 1, end)
        if j < 0:
            return False
        if plausible is None or len(buf) < end + 2:
            return None
        return plausible

    def _aligned_after(self, end: int) -> bool:
        """Frames are sent back to back: the next one starts right after a real frame."""
        return self._buf[end:end + 2] == SYNC

    def feed(self, data: bytes) -> list[Frame]:
        """Append bytes; return every complete valid frame now available, oldest first."""
        buf = self._buf
        buf += data
        out: list[Frame] = []
        while True:
            i = buf.find(SYNC)
            if i < 0:
                # a trailing A5 may be the first half of the next sync
                keep = 1 if buf.endswith(SYNC[:1]) else 0
                if len(buf) - keep > 0:
                    self._skip_garbage(len(buf) - keep)
                return out
            if i > 0:
                self._skip_garbage(i)
            if len(buf) < 4:
                return out
            length, ftype = buf[2], buf[3]
            if length > self.max_payload:
                self.bad_length += 1
                self._skipping = False
                self._reject("bad_length", ftype)
                self._skip(2)  # drop this sync; the next search finds the real one
                continue
            end = length + FRAME_OVERHEAD
            if len(buf) < end:
                return out
            crc_ok = crc16_ccitt_false(bytes(buf[2:end - 2])) == (buf[end - 2] | buf[end - 1] << 8)
            if crc_ok:
                inner = self._inner_header(end)
                if inner is None:
                    return out  # decide when the bytes that tell are here
                if inner and not self._aligned_after(end):
                    # A 16-bit CRC passes a cut frame spliced with its successor once in
                    # 65536: a header inside and no sync right after means exactly that.
                    crc_ok = False
            if crc_ok:
                out.append(Frame(ftype, bytes(buf[4:end - 2])))
                self.frames += 1
                self._skipping = False
                del buf[:end]
                continue
            # The CRC failed. If a frame header starts inside, this frame was cut short and
            # the next frame's bytes were read as its tail: resume at that header.
            j = buf.find(SYNC, 1, end)
            while j > 0:
                plausible = self._header_at(j)
                if plausible is None:
                    return out  # decide when the header's bytes are here
                if plausible:
                    break
                j = buf.find(SYNC, j + 1, end)
            self._skipping = False
            if j > 0:
                self.truncated += 1
                self._reject("truncated", ftype)
                self._skip(j)
            else:
                self.crc_errors += 1
                self._reject("crc", ftype)
                self._skip(end)

    def flush(self) -> int:
        """End of stream: a partial frame still held is counted as truncated. Returns bytes dropped."""
        n = len(self._buf)
        if n:
            if self._buf.startswith(SYNC) and n >= 3:
                self.truncated += 1
                self._reject("truncated", self._buf[3] if n > 3 else 0)
                self._skip(n)
            else:
                self._skip_garbage(n)
        self._skipping = False
        return n


class SequenceTracker:
    """Checks sample sequence numbers: gaps (frames lost), out-of-order, device restarts.

    `bits` is the width of the sequence field (32 on serial, 7 on CAN). With a short field,
    pass `elapsed_periods` (device time since the last accepted sample / sample period) so
    a gap longer than the field's range is still counted right.
    An out-of-order (older or repeated) frame is rejected; eight consecutive frames that
    are consecutive among themselves but behind the last accepted one mean the device
    restarted, and the tracker follows it.
    """

    RESTART_RUN = 8

    def __init__(self, bits: int = 32) -> None:
        self.mod = 1 << bits
        self.last: int | None = None
        self.gaps = 0
        self.lost = 0
        self.out_of_order = 0
        self.restarts = 0
        self._behind_last: int | None = None
        self._behind_run = 0

    def reset(self) -> None:
        self.last = None
        self._behind_last, self._behind_run = None, 0

    def accept(self, seq: int, elapsed_periods: float | None = None) -> bool:
        """True if the sample is new and in order (then it is the newest)."""
        if self.last is None:
            self.last = seq
            return True
        diff = (seq - self.last) % self.mod
        if elapsed_periods is not None:
            # unfold the short counter with the device clock: the nearest whole wrap count
            diff += self.mod * round((elapsed_periods - diff) / self.mod)
            forward = diff > 0
        else:
            forward = 0 < diff < self.mod // 2
        if forward:
            if diff > 1:
                self.gaps += 1
                self.lost += diff - 1
            self.last = seq
            self._behind_last, self._behind_run = None, 0
            return True
        self.out_of_order += 1
        if self._behind_last is not None and (seq - self._behind_last) % self.mod == 1:
            self._behind_run += 1
        else:
            self._behind_run = 1
        self._behind_last = seq
        if self._behind_run >= self.RESTART_RUN:
            # the run was counted as out-of-order one by one; it was a restart instead
            self.out_of_order -= self._behind_run
            self.restarts += 1
            self.last = seq
            self._behind_last, self._behind_run = None, 0
            return True
        return False


class ClockMapper:
    """Maps device micros() (u32, wraps every 71.6 min) to host seconds.

    The serial link only ever delays a frame, so host_rx - device_time is the clock offset
    plus a non-negative delay; its minimum over a block of samples is close to the offset.
    A line through the last `blocks` block minima follows the Arduino's crystal drift
    (a ceramic resonator is good to ~0.1-0.5 %, i.e. up to 5 ms/s).
    Call `map` only for accepted (in-order) samples.
    """

    def __init__(self, block_s: float = 0.5, blocks: int = 16) -> None:
        self.block_s = block_s
        self._blocks: deque[tuple[float, float]] = deque(maxlen=blocks)
        self._last_us: int | None = None
        self._ext_us = 0
        self._block_start: float | None = None
        self._block_min: tuple[float, float] | None = None
        self._global_min = math.inf
        self._last_t = -math.inf

    def device_seconds(self, t_us: int) -> float:
        """Unwrapped device time (s) since the first sample's micros() epoch."""
        if self._last_us is None:
            self._ext_us = t_us
        else:
            self._ext_us += (t_us - self._last_us) & 0xFFFFFFFF
        self._last_us = t_us
        return self._ext_us * 1e-6

    def map(self, t_us: int, host_rx: float) -> float:
        dev = self.device_seconds(t_us)
        d = host_rx - dev
        if self._block_start is None:
            self._block_start = dev
        if self._block_min is None or d < self._block_min[1]:
            self._block_min = (dev, d)
        self._global_min = min(self._global_min, d)
        if dev - self._block_start >= self.block_s:
            self._blocks.append(self._block_min)
            self._block_start, self._block_min = dev, None
        offset = self.offset(dev)
        if self._block_min is not None:
            offset = min(offset, self._block_min[1])
        # never after its arrival; never before the previous sample (a new fit may step back)
        t = max(min(dev + offset, host_rx), self._last_t)
        self._last_t = t
        return t

    def offset(self, dev: float) -> float:
        """Estimated host - device clock offset (s) at device time `dev` (s)."""
        pts = self._blocks
        if len(pts) < 2:
            return self._global_min
        n = len(pts)
        mx = sum(p[0] for p in pts) / n
        my = sum(p[1] for p in pts) / n
        sxx = sum((p[0] - mx) ** 2 for p in pts)
        slope = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx if sxx > 0 else 0.0
        # the fit runs through the block minima's mean; shift it down onto their envelope
        resid = min(p[1] - (my + slope * (p[0] - mx)) for p in pts)
        return my + slope * (dev - mx) + resid


# --------------------------------------------------------------------------- calibration

STANDARD_GRAVITY = 9.80665  # m/s^2


class LoadCellError(DeviceFault):
    """Anything wrong with the load cell that a procedure should stop on."""


class LoadCellDisconnected(LoadCellError):
    """The port died, or no frame arrived within the stale timeout."""


class LoadCellCommandError(LoadCellError):
    """The device answered a command with an error reply, or did not answer."""


class LoadCellNotCalibrated(LoadCellError):
    """Newtons were asked for but no calibration is loaded."""


@dataclass(frozen=True)
class LoadCellCalibration:
    """counts -> newtons: force = (counts - zero_counts - tare_counts) * newtons_per_count.

    Built from two known masses m1, m2 (kg) hung from the cell, read as mean counts c1, c2:
    newtons_per_count = g (m2 - m1) / (c2 - c1), zero_counts = c1 - g m1 / newtons_per_count.
    `tare_counts` shifts the zero so that the load present at the last tare reads 0 N.
    """

    newtons_per_count: float
    zero_counts: float
    tare_counts: float = 0.0
    mass1_kg: float | None = None
    mass2_kg: float | None = None
    counts1: float | None = None
    counts2: float | None = None
    counts1_sem: float | None = None  # standard error of the mean counts at mass 1
    counts2_sem: float | None = None
    newtons_per_count_std: float | None = None  # 1-sigma, from the two standard errors
    g: float = STANDARD_GRAVITY
    created: str = ""
    device: str = ""

    @classmethod
    def from_two_points(cls, mass1_kg: float, counts1: float, mass2_kg: float, counts2: float,
                        counts1_sem: float = 0.0, counts2_sem: float = 0.0,
                        g: float = STANDARD_GRAVITY, device: str = "") -> "LoadCellCalibration":
        if not all(map(math.isfinite, (mass1_kg, mass2_kg, counts1, counts2))):
            raise ValueError("load-cell calibration: masses and counts must be finite numbers")
        if mass1_kg == mass2_kg:
            raise ValueError("load-cell calibration: the two masses must differ")
        dc = counts2 - counts1
        noise = math.hypot(counts1_sem, counts2_sem)
        if abs(dc) < max(5.0, 10.0 * noise):
            raise ValueError(
                f"load-cell calibration: counts changed by only {dc:.1f} between {mass1_kg} kg and "
                f"{mass2_kg} kg (noise {noise:.1f} counts); check that the mass hangs from the cell")
        k = g * (mass2_kg - mass1_kg) / dc
        from datetime import datetime, timezone
        return cls(newtons_per_count=k, zero_counts=counts1 - g * mass1_kg / k,
                   mass1_kg=mass1_kg, mass2_kg=mass2_kg, counts1=counts1, counts2=counts2,
                   counts1_sem=counts1_sem, counts2_sem=counts2_sem,
                   newtons_per_count_std=abs(k) * noise / abs(dc), g=g,
                   created=datetime.now(timezone.utc).isoformat(), device=device)

    def newtons(self, counts: float) -> float:
        return (counts - self.zero_counts - self.tare_counts) * self.newtons_per_count

    def with_tare(self, counts_at_zero: float) -> "LoadCellCalibration":
        """The same calibration, zeroed so that `counts_at_zero` reads 0 N."""
        return replace(self, tare_counts=counts_at_zero - self.zero_counts)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict, source: str = "calibration") -> "LoadCellCalibration":
        try:
            cal = cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})
        except TypeError as exc:
            raise LoadCellNotCalibrated(f"{source}: not a load-cell calibration ({exc})") from None
        for name in ("newtons_per_count", "zero_counts", "tare_counts"):
            v = getattr(cal, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise LoadCellNotCalibrated(f"{source}: field '{name}' must be a finite number, got {v!r}")
        if cal.newtons_per_count == 0:
            raise LoadCellNotCalibrated(f"{source}: field 'newtons_per_count' is zero")
        return cal

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> "LoadCellCalibration":
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise LoadCellNotCalibrated(f"{path}: no such calibration file") from None
        except json.JSONDecodeError as exc:
            raise LoadCellNotCalibrated(f"{path}: line {exc.lineno}: not valid JSON ({exc.msg})") from None
        return cls.from_dict(data.get("calibration", data), source=str(path))


def open_serial_port(path: str, baudrate: int):
    """The load cell's serial port opened with pyserial; a port that cannot be opened is a
    LoadCellDisconnected naming it and what to check."""
    import serial

    try:
        return serial.Serial(path, baudrate, timeout=0.005)
    except (serial.SerialException, OSError, ValueError) as exc:
        why = getattr(exc, "strerror", None) or str(exc)
        raise LoadCellDisconnected(f"load cell port {path}: cannot open ({why}); check the cable, the "
                                   "port in rig.toml [loadcell] (or `rig sim`'s printed pty)") from None


def usb_serial_number(port: str) -> str:
    """The USB serial number of the device behind `port` (a /dev/serial/by-id link is
    followed), as the operating system reports it; "" for a pty or an unknown port."""
    try:
        from serial.tools import list_ports

        real = os.path.realpath(port)
        for info in list_ports.comports():
            if os.path.realpath(info.device) == real:
                return info.serial_number or ""
    except Exception:  # noqa: BLE001 - no enumeration on this platform: the port names the cell
        return ""
    return ""


# --------------------------------------------------------------------------- host driver

@dataclass
class LoadCellStats:
    """What the driver received and rejected since it started (events; `lost` in frames)."""

    frames_ok: int = 0
    samples: int = 0
    replies: int = 0
    crc_errors: int = 0
    truncated: int = 0
    bad_length: int = 0
    resyncs: int = 0
    bytes_discarded: int = 0
    gaps: int = 0
    lost: int = 0  # sequence numbers never received
    out_of_order: int = 0
    restarts: int = 0
    saturated: int = 0
    dropped: int = 0  # received but overwritten before anyone called samples()
    device_errors: int = 0  # error replies from the device

    def problems(self) -> int:
        return (self.crc_errors + self.truncated + self.bad_length + self.resyncs + self.lost
                + self.out_of_order + self.restarts + self.dropped)

    def table(self) -> str:
        return "\n".join(f"{k:>16} {v}" for k, v in asdict(self).items())


class _StreamingLoadCell(abc.ABC):
    """Sample buffering, staleness, calibration and commands shared by serial and CAN drivers."""

    def __init__(self, calibration: LoadCellCalibration | None, stale_timeout: float,
                 clock: Callable[[], float], on_sample: Callable[[ForceSample, float], None] | None,
                 buffer_size: int, name: str) -> None:
        self.calibration = calibration
        self.stale_timeout = stale_timeout
        self.clock = clock
        self.on_sample = on_sample
        self.name = name
        self._lock = threading.Lock()
        self._buffer: deque[ForceSample] = deque()
        self._buffer_size = buffer_size
        self._latest: ForceSample | None = None
        self._last_rx: float | None = None
        self._last_poll: float | None = None  # clock() when the reader last looked at the transport
        self._device_times: deque[float] = deque(maxlen=64)  # device s of the newest samples (their rate)
        self._streaming = False
        self._error: LoadCellError | None = None
        self._replies: queue.Queue[tuple[int, bytes]] = queue.Queue()
        self._cmd_lock = threading.Lock()
        self._stop = threading.Event()
        self._stats = LoadCellStats()
        self._seq = SequenceTracker(self._seq_bits)
        self._clockmap = ClockMapper()
        self.rate_hz = 0
        self.identity: Identity | None = None
        self._tare_pending = False

    _seq_bits = 32
    #: the rig.toml key of `stale_timeout`, named by the stale line
    setting = "[loadcell] stale_timeout"
    connect_timeout = 2.5  # s, covers the Arduino bootloader after a DTR reset

    # ---- reader-thread side
    def _fail(self, error: LoadCellError) -> None:
        with self._lock:
            if self._error is None:
                self._error = error

    def _check_stale(self, now: float) -> None:
        if self._streaming and self._error is None and self._last_rx is not None:
            age = now - self._last_rx
            if age > self.stale_timeout:
                self._fail(LoadCellDisconnected(self._stale_line(age)))

    def _stale_line(self, age: float) -> str:
        """The one line of a cell silent for `age` s: how long, at what rate its samples had
        been coming (the device's own clock; the rate it was set to before two samples),
        the limit and its key, and that a starved process looks the same as a dead cable."""
        with self._lock:
            rate = rate_of(self._device_times) or float(self.rate_hz)
        return (f"load cell on {self.name}: {silence_text(age, rate, noun='sample')}, beyond the stale timeout "
                f"{self.stale_timeout * 1e3:.0f} ms ({self.setting}). "
                + starved_text(self.setting, "the cell is plugged in and powered (or `rig sim` runs)",
                               "check the cable and power"))

    def _on_raw_sample(self, s: RawSample, rx: float, elapsed_periods: float | None = None) -> bool:
        """Deliver one decoded sample; False if it was out of order (counted, not delivered)."""
        st = self._stats
        if not self._seq.accept(s.seq, elapsed_periods):
            return False
        t = self._clockmap.map(s.t_us, rx)
        device_t = self._clockmap._ext_us * 1e-6  # the unwrapped device time map() just took
        cal = self.calibration
        force = cal.newtons(s.counts) if cal is not None else math.nan
        sample = ForceSample(t=t, force=force, raw=s.counts, seq=s.seq)
        with self._lock:
            st.samples += 1
            if s.saturated:
                st.saturated += 1
            if len(self._buffer) >= self._buffer_size:
                self._buffer.popleft()
                st.dropped += 1
            self._buffer.append(sample)
            self._latest = sample
            self._last_rx = rx
            self._device_times.append(device_t)
        if self.on_sample is not None:
            self.on_sample(sample, rx)
        return True

    def _on_reply(self, ftype: int, payload: bytes) -> None:
        if ftype == CMD_TARE | REPLY and self._tare_pending and len(payload) == TARE_REPLY_FMT.size:
            # re-zero here, in the reader thread, so every sample decoded after the reply
            # (the firmware sends it before the next sample) reads against the new zero
            with self._lock:
                self._tare_pending = False
                if self.calibration is not None:
                    self.calibration = self.calibration.with_tare(TARE_REPLY_FMT.unpack(payload)[0])
        self._stats.replies += 1
        if ftype == T_ERROR:
            self._stats.device_errors += 1
        self._replies.put((ftype, payload))

    # ---- caller side
    def _raise_if_unusable(self) -> None:
        if self._error is not None:
            raise self._error
        if not self._streaming:
            raise LoadCellError(f"load cell on {self.name} is not streaming; call start()")
        self._check_stale(self._polled_now())
        if self._error is not None:
            raise self._error

    def _polled_now(self) -> float:
        """Now, as far as the reader thread has looked: a starved reader (the process busy)
        has not seen the samples waiting in the port, which must not count as silence."""
        now = self.clock()
        poll = self._last_poll
        return now if poll is None else min(now, poll)

    def stream_age(self) -> float:
        """Seconds since the last sample as of the reader's last look (inf before the first)."""
        rx = self._last_rx
        return float("inf") if rx is None else self._polled_now() - rx

    def read(self) -> ForceSample:
        """The newest sample (N, host seconds). Raises if disconnected, stale or uncalibrated."""
        with self._lock:
            latest = self._latest
        self._raise_if_unusable()
        if self.calibration is None:
            raise LoadCellNotCalibrated(
                f"load cell on {self.name}: no calibration loaded; run `rig loadcell-calibrate`")
        if latest is None:
            raise LoadCellDisconnected(f"load cell on {self.name}: no sample received yet")
        return latest

    def samples(self) -> list[ForceSample]:
        """Every sample since the last call, oldest first.

        Samples received before a disconnect are returned first; the error is raised on
        the next call that finds nothing new.
        """
        out = self.raw_samples()
        if out and self.calibration is None:
            raise LoadCellNotCalibrated(
                f"load cell on {self.name}: no calibration loaded; run `rig loadcell-calibrate`")
        return out

    def raw_samples(self) -> list[ForceSample]:
        """Like samples() but without a calibration (force is NaN when none is loaded)."""
        with self._lock:
            out = list(self._buffer)
            self._buffer.clear()
        if not out and (self._streaming or self._error is not None):
            self._raise_if_unusable()  # after stop(), nothing new is simply nothing
        return out

    def stats(self) -> LoadCellStats:
        """A snapshot of the counters."""
        with self._lock:
            return replace(self._stats)

    def collect_counts(self, seconds: float) -> list[int]:
        """Raw counts of the samples converted during the next `seconds` (s).

        Selected by their (mapped) conversion time, so a sample taken before the call but
        delivered late is not mixed in. The window is complete when a sample converted
        after its end has arrived (on a loaded host the last ones come tens of ms late), or
        at the latest a stale timeout after its end.
        """
        start = self.clock()
        end = start + seconds
        out: list[int] = []
        while True:
            late = self.clock() >= end + max(0.02, self.stale_timeout)
            new = self.raw_samples()
            out.extend(s.raw for s in new if start <= s.t < end)
            if late or any(s.t >= end for s in new):
                return out
            time.sleep(0.005)

    @abc.abstractmethod
    def _send(self, ctype: int, payload: bytes) -> None:
        """Put one command on the transport (a framed serial write, or a CAN frame)."""

    def close(self) -> None:
        """Stop streaming (if the device still answers) and the reader thread. Leaves the
        transport (port or bus) open: whoever opened it closes it."""
        if self._error is None and self._streaming:
            try:
                self.stop()
            except LoadCellError:
                pass
        self._stop.set()
        self._thread.join(timeout=1.0)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def command(self, ctype: int, payload: bytes = b"", timeout: float | None = None) -> bytes:
        """Send one command and return its reply payload (within `timeout` s, default
        COMMAND_TIMEOUT); raises LoadCellCommandError."""
        timeout = COMMAND_TIMEOUT if timeout is None else timeout
        with self._cmd_lock:
            if self._error is not None:
                raise self._error
            while not self._replies.empty():  # late replies to earlier timed-out commands
                self._replies.get_nowait()
            self._send(ctype, payload)
            end = time.monotonic() + timeout
            while True:
                left = end - time.monotonic()
                if left <= 0:
                    if self._error is not None:
                        raise self._error
                    raise LoadCellCommandError(
                        f"load cell on {self.name}: no reply to {COMMAND_NAMES.get(ctype, hex(ctype))} "
                        f"within {timeout * 1e3:.0f} ms")
                try:
                    rtype, rpayload = self._replies.get(timeout=min(left, 0.02))
                except queue.Empty:
                    if self._error is not None:
                        raise self._error
                    continue
                if rtype == ctype | REPLY:
                    return rpayload
                if rtype == T_ERROR and len(rpayload) == 2 and rpayload[0] == ctype:
                    raise LoadCellCommandError(
                        f"load cell on {self.name}: {COMMAND_NAMES.get(ctype, hex(ctype))} refused: "
                        f"{ERROR_NAMES.get(rpayload[1], f'error {rpayload[1]:#04x}')}")
                # an error about a different (garbled) command, or a stray reply: keep waiting

    def identify(self, timeout: float = 0.5) -> Identity:
        ident = decode_identity(self.command(CMD_IDENTIFY, timeout=timeout))
        if ident.protocol != PROTOCOL_VERSION:
            raise LoadCellError(f"load cell on {self.name} speaks protocol {ident.protocol}, "
                                f"this driver speaks {PROTOCOL_VERSION}; update the firmware or the package")
        self.identity = ident
        return ident

    def status(self) -> Status:
        return decode_status(self.command(CMD_STATUS))

    def set_rate(self, rate_hz: int) -> int:
        """Sample rate (Hz); returns the rate the device took."""
        self.rate_hz = RATE_FMT.unpack(self.command(CMD_SET_RATE, RATE_FMT.pack(rate_hz)))[0]
        return self.rate_hz

    def start(self) -> None:
        self.command(CMD_START)
        with self._lock:
            self._last_rx = self.clock()  # the stale clock starts now
            self._streaming = True

    def stop(self) -> None:
        with self._lock:
            self._streaming = False
        self.command(CMD_STOP)

    def tare_counts(self, conversions: int = 64) -> int:
        """Ask the device for the mean of its next `conversions` readings (counts)."""
        if not 1 <= conversions <= 255:
            raise ValueError("conversions must be 1..255")
        # the averaging, plus a margin for a host under load (bench_hil with two CPU burners
        # and three cells: a reply came more than 0.5 s after the averaging ended)
        timeout = 1.5 + conversions / max(self.rate_hz, 1)
        mean, _n = TARE_REPLY_FMT.unpack(self.command(CMD_TARE, TARE_CMD_FMT.pack(conversions), timeout))
        return mean

    def tare(self, conversions: int = 64) -> None:
        """Zero the force at the present load (device-averaged over `conversions` samples).

        Samples converted after the device's tare reply read against the new zero; those
        already received keep the force they had.
        """
        if self.calibration is None:
            raise LoadCellNotCalibrated(
                f"load cell on {self.name}: tare needs a calibration; run `rig loadcell-calibrate`")
        self._tare_pending = True
        try:
            self.tare_counts(conversions)  # the reader thread applies the reply
        finally:
            self._tare_pending = False

    def _no_reply(self, exc: Exception) -> str:
        """What a device that never answers IDENTIFY asks the user to check, first the
        baud rate (a firmware at another rate answers nothing the parser can frame)."""
        baud = getattr(getattr(self, "port", None), "baudrate", None)
        at = f" at {baud} baud" if baud else ""
        return (f"load cell on {self.name}: no reply to IDENTIFY within {self.connect_timeout:g} s{at}; check "
                f"the baud rate ([loadcell] baudrate; the rig's firmware talks at {BAUDRATE}), that the board "
                "runs the rig's firmware (drivers/firmware/loadcell), the port and the cable")

    def _setup(self, rate_hz: int, start: bool) -> None:
        try:
            # an Uno/Nano resets when the port opens and its bootloader listens for ~1.5 s,
            # so the first IDENTIFYs may go unanswered
            deadline = time.monotonic() + self.connect_timeout
            while True:
                try:
                    self.identify(timeout=0.25)
                    break
                except LoadCellCommandError as exc:
                    if self._error is not None:
                        raise
                    if time.monotonic() > deadline:
                        raise LoadCellCommandError(self._no_reply(exc)) from None
            if self.identity is not None and rate_hz > self.identity.max_rate_hz:
                raise LoadCellError(
                    f"load cell on {self.name}: {rate_hz} Hz asked, the "
                    f"{ADC_NAMES.get(self.identity.adc, 'ADC')} firmware allows {self.identity.max_rate_hz} Hz")
            self.set_rate(rate_hz)
            if start:
                self.start()
        except BaseException:
            # the reader must be gone before the caller retries on the same port,
            # or two threads would split the replies between them
            self._stop.set()
            self._thread.join(timeout=1.0)
            raise


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
                 buffer_size: int = 65536, start: bool = True) -> None:
        super().__init__(calibration, stale_timeout, clock, on_sample, buffer_size,
                         name=str(getattr(port, "port", None) or getattr(port, "name", None) or port))
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


# --------------------------------------------------------------------------- firmware fake

class LoadCellDeviceModel:
    """The firmware's state and its ADC, without a transport (shared by the serial and CAN fakes).

    Force to counts: counts = offset_counts + gain_counts_per_newton * F, where
    F = tension_source() + drift * (t - t0) + N(0, noise) (N, N/s, N rms), clipped to
    `adc_limits` (counts) with the saturated flag set. The defaults model the INA build:
    an instrumentation amplifier at 0.1 V/N around 2.5 V into the 10-bit ADC, 16 readings
    summed: 16 * 1024 counts / 5 V * 0.1 V/N = 327.68 counts/N, range about +-25 N.
    Device time is `clock()` (s) scaled by (1 + clock_ppm 1e-6) plus `micros_start` (us),
    as micros() would give it.
    """

    def __init__(self, tension_source: Callable[[], float], clock: Callable[[], float] | None = None, *,
                 gain_counts_per_newton: float = 327.68, offset_counts: float = 137.0,
                 adc_limits: tuple[int, int] = (-8192, 8176), noise: float = 0.0, drift: float = 0.0,
                 adc: int = ADC_INA, max_rate_hz: int = 1000, rate_hz: int = 500,
                 micros_start: int = 0, clock_ppm: float = 0.0, seed: int = 0) -> None:
        self.tension_source = tension_source
        self.clock = clock or time.monotonic
        self.gain = gain_counts_per_newton
        self.offset = offset_counts
        self.adc_limits = adc_limits
        self.noise = noise
        self.drift = drift
        self.adc = adc
        self.max_rate_hz = max_rate_hz
        self.rate_hz = rate_hz
        self.micros_start = micros_start
        self.clock_ppm = clock_ppm
        self.rng = random.Random(seed)
        self.t0 = self.clock()
        self.seq = 0
        self.streaming = False
        self.rx_errors = 0
        self.tx_dropped = 0
        self.last_saturated = False
        self._tare_left = 0
        self._tare_n = 0
        self._tare_sum = 0

    def micros(self) -> int:
        dt = self.clock() - self.t0
        return int(self.micros_start + dt * (1.0 + self.clock_ppm * 1e-6) * 1e6) & 0xFFFFFFFF

    def true_counts(self, force: float) -> float:
        """Counts the ADC would give for `force` (N), before noise and clipping."""
        return self.offset + self.gain * force

    def convert(self) -> tuple[int, bool]:
        """One ADC conversion of the present tension: (counts, saturated)."""
        f = self.tension_source() + self.drift * (self.clock() - self.t0)
        if self.noise > 0:
            f += self.rng.gauss(0.0, self.noise)
        c = round(self.true_counts(f))
        lo, hi = self.adc_limits
        if c <= lo or c >= hi:
            return (lo if c <= lo else hi), True
        return c, False

    def tick(self) -> tuple[RawSample | None, list[tuple[int, bytes]]]:
        """One sample period: convert; finish a tare; the sample to send if streaming."""
        t_us = self.micros()
        counts, sat = self.convert()
        self.last_saturated = sat
        replies: list[tuple[int, bytes]] = []
        if self._tare_left > 0:
            self._tare_sum += counts
            self._tare_left -= 1
            if self._tare_left == 0:
                # round half away from zero, like the sketch's integer arithmetic
                n = self._tare_n
                mean = int((abs(self._tare_sum) + n // 2) // n) * (1 if self._tare_sum >= 0 else -1)
                replies.append((CMD_TARE | REPLY, TARE_REPLY_FMT.pack(mean, n)))
        sample = None
        if self.streaming:
            sample = RawSample(self.seq, t_us, counts, SAMPLE_SATURATED if sat else 0)
            self.seq = (self.seq + 1) & 0xFFFFFFFF
        return sample, replies

    def identity(self) -> Identity:
        return Identity(PROTOCOL_VERSION, FIRMWARE_VERSION, self.adc, self.max_rate_hz)

    def status(self) -> Status:
        flags = ((STATUS_STREAMING if self.streaming else 0) | (STATUS_TARE_BUSY if self._tare_left else 0)
                 | (STATUS_SATURATED if self.last_saturated else 0))
        return Status(self.rate_hz, flags, self.rx_errors, self.tx_dropped)

    def handle(self, ctype: int, payload: bytes) -> list[tuple[int, bytes]]:
        """One received command -> the immediate replies (a tare replies from tick())."""
        if ctype not in COMMAND_PAYLOAD_LEN:
            self.rx_errors += 1
            return [(T_ERROR, ERROR_FMT.pack(ctype, ERR_UNKNOWN_COMMAND))]
        if len(payload) != COMMAND_PAYLOAD_LEN[ctype]:
            self.rx_errors += 1
            return [(T_ERROR, ERROR_FMT.pack(ctype, ERR_BAD_LENGTH))]
        if ctype == CMD_IDENTIFY:
            return [(ctype | REPLY, identity_payload(self.identity()))]
        if ctype == CMD_STATUS:
            return [(ctype | REPLY, status_payload(self.status()))]
        if ctype == CMD_SET_RATE:
            (rate,) = RATE_FMT.unpack(payload)
            if not 1 <= rate <= self.max_rate_hz:
                return [(T_ERROR, ERROR_FMT.pack(ctype, ERR_BAD_ARGUMENT))]
            self.rate_hz = rate
            return [(ctype | REPLY, RATE_FMT.pack(rate))]
        if ctype == CMD_START:
            self.streaming = True
            return [(ctype | REPLY, b"")]
        if ctype == CMD_STOP:
            self.streaming = False
            return [(ctype | REPLY, b"")]
        # CMD_TARE
        (n,) = TARE_CMD_FMT.unpack(payload)
        if n == 0:
            return [(T_ERROR, ERROR_FMT.pack(ctype, ERR_BAD_ARGUMENT))]
        if self._tare_left:
            return [(T_ERROR, ERROR_FMT.pack(ctype, ERR_BUSY))]
        self._tare_left, self._tare_n, self._tare_sum = n, n, 0
        return []

    def reject(self, kind: str, ftype: int) -> list[tuple[int, bytes]]:
        """A command frame the parser refused -> the error reply the sketch sends."""
        self.rx_errors += 1
        code = {"crc": ERR_BAD_CRC, "truncated": ERR_INCOMPLETE, "bad_length": ERR_BAD_LENGTH}.get(kind)
        return [(T_ERROR, ERROR_FMT.pack(ftype, code))] if code else []


class FakeLoadCellFirmware:
    """The sketch, emulated on a pseudo-terminal: open `port_path` with `serial.Serial`.

    Runs in its own thread once started (`start()` or `with`). The model (`.model`) holds
    the physics: `tension_source()` (N) and `clock()` (s) feed it; `noise` (N rms),
    `drift` (N/s) and `adc_limits` (counts) are settable at any time. Faults:
    `corrupt_probability` (each sample frame gets one bit flipped with that probability),
    `inject(kind, count)` for the next `count` sample frames with kind in
    {"crc", "truncate", "garbage", "skip", "swap"}, and `unplug()` (closes the pty).
    Like the Arduino's 64-byte serial buffer, a frame that does not fit in the output
    backlog is dropped (its sequence number is used, so the host sees a gap).
    `write_times` (if `record_write_times`) maps seq -> time.monotonic() right after the
    frame was written to the pty: a side channel for latency benchmarks.
    """

    TX_BACKLOG = 64  # bytes, the Arduino core's TX ring buffer

    def __init__(self, tension_source: Callable[[], float], clock: Callable[[], float] | None = None, *,
                 record_write_times: bool = False, seed: int = 0, **model_kwargs) -> None:
        self.model = LoadCellDeviceModel(tension_source, clock, seed=seed, **model_kwargs)
        self.rng = random.Random(seed + 1)
        self.corrupt_probability = 0.0
        self._inject: deque[str] = deque()
        self._swap_held: bytes | None = None
        self.injected: dict[str, int] = {}
        self.frames_sent = 0
        self.record_write_times = record_write_times
        self.write_times: dict[int, float] = {}
        self.sample_times: dict[int, float] = {}  # seq -> clock() at conversion (truth for time mapping)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation: a byte pipe like a USB CDC port
        os.set_blocking(self._master, False)
        self.port_path = os.ttyname(self._slave)
        self._tx = bytearray()
        self._rx_last = 0.0
        self._parser = FrameParser(on_reject=self._on_reject)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._fd_lock = threading.Lock()
        self.unplugged = False

    # settable faults, forwarded to the model for convenience
    noise = property(lambda self: self.model.noise, lambda self, v: setattr(self.model, "noise", v))
    drift = property(lambda self: self.model.drift, lambda self, v: setattr(self.model, "drift", v))
    adc_limits = property(lambda self: self.model.adc_limits,
                          lambda self, v: setattr(self.model, "adc_limits", v))

    def inject(self, kind: str, count: int = 1) -> None:
        if kind not in ("crc", "truncate", "garbage", "skip", "swap"):
            raise ValueError(f"unknown fault kind {kind!r}")
        self._inject.extend([kind] * count)

    def start(self) -> "FakeLoadCellFirmware":
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="fake-loadcell", daemon=True)
            self._thread.start()
        return self

    def __enter__(self) -> "FakeLoadCellFirmware":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _on_reject(self, kind: str, ftype: int) -> None:
        for rtype, payload in self.model.reject(kind, ftype):
            self._queue(encode_frame(rtype, payload), is_sample=False)

    def _queue(self, frame: bytes, is_sample: bool) -> bool:
        if is_sample and len(self._tx) + len(frame) > self.TX_BACKLOG:
            self.model.tx_dropped += 1
            return False
        self._tx += frame
        return True

    def _flush(self) -> None:
        if not self._tx:
            return
        try:
            n = os.write(self._master, self._tx)
        except BlockingIOError:
            return
        del self._tx[:n]

    def _fault(self, frame: bytes) -> bytes:
        kind = self._inject.popleft() if self._inject else None
        if kind == "swap" and self._swap_held is not None:
            self._inject.appendleft(kind)  # one swap at a time: apply it after this pair
            kind = None
        if kind is None and self.corrupt_probability > 0 and self.rng.random() < self.corrupt_probability:
            kind = "crc"
        if kind is None:
            return frame
        self.injected[kind] = self.injected.get(kind, 0) + 1
        if kind == "crc":
            b = bytearray(frame)
            b[4 + self.rng.randrange(len(frame) - FRAME_OVERHEAD)] ^= 1 << self.rng.randrange(8)
            return bytes(b)
        if kind == "truncate":
            return frame[:self.rng.randrange(5, len(frame) - 1)]
        if kind == "garbage":
            # garbage that cannot contain a sync pattern, so the count is exact
            return bytes(self.rng.choice([0x00, 0x11, 0xFF, 0x5A, 0x42]) for _ in range(7)) + frame
        if kind == "skip":
            return b""
        # swap: hold this frame back and send it right after the next one
        self._swap_held = frame
        return b""

    def _send_sample(self, s: RawSample) -> None:
        frame = sample_frame(s)
        if len(self._tx) + len(frame) > self.TX_BACKLOG:
            self.model.tx_dropped += 1  # dropped before any fault is spent on it
            return
        frame = self._fault(frame)
        n = 1
        if frame and self._swap_held is not None:
            frame, self._swap_held, n = frame + self._swap_held, None, 2
        if frame and self._queue(frame, is_sample=True):
            self.frames_sent += n
            self._flush()
            if self.record_write_times:
                self.write_times[s.seq] = time.monotonic()

    def _run(self) -> None:
        m = self.model
        next_t = time.monotonic()
        while not self._stop.is_set():
            wait = max(0.0, next_t - time.monotonic())
            try:
                readable, _, _ = select.select([self._master], [], [], wait)
                if readable:
                    data = os.read(self._master, 256)
                    self._rx_last = time.monotonic()
                    for f in self._parser.feed(data):
                        for rtype, payload in m.handle(f.type, f.payload):
                            self._queue(encode_frame(rtype, payload), is_sample=False)
                elif self._parser.pending and time.monotonic() - self._rx_last > 0.05:
                    self._parser.flush()  # a command that stopped half-way (reported via _on_reject)
                now = time.monotonic()
                if now >= next_t:
                    sample, replies = m.tick()
                    for rtype, payload in replies:
                        self._queue(encode_frame(rtype, payload), is_sample=False)
                    if sample is not None:
                        if self.record_write_times:
                            self.sample_times[sample.seq] = m.clock()
                        self._send_sample(sample)
                    next_t += 1.0 / m.rate_hz
                    if now - next_t > 0.1:  # stalled far behind (debugger, suspend): do not burst
                        next_t = now
                self._flush()
            except OSError:
                if self._stop.is_set():
                    return
                # EIO: nobody holds the slave end any more; keep running like a device whose
                # USB host went away
                time.sleep(0.01)

    def unplug(self) -> None:
        """Pull the USB cable: stop the firmware and close both ends of the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        with self._fd_lock:
            if not self.unplugged:
                self.unplugged = True
                for fd in (self._master, self._slave):
                    try:
                        os.close(fd)
                    except OSError:
                        pass

    close = unplug
