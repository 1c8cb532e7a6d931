"""The load cell's wire protocol: frame layout, message types, payload formats, CRC-16/CCITT-FALSE."""

from __future__ import annotations

import struct
from dataclasses import dataclass

PROTOCOL_VERSION = 1
#: baud of the serial link: the firmware's LOADCELL_BAUD (firmware/loadcell/loadcell.ino), the one
#: place the host side takes it from (rig.toml's [loadcell] baudrate default). 250000 is exact on a
#: 16 MHz AVR (115200 is 2 % off there) and carries a 500 Hz stream at 38 % of the line.
BAUDRATE = 250000

#: s, longest wait for a command's reply. The firmware answers within a few ms; the margin is
#: for the host's reader thread, held off the CPU on a starved machine (two CPU burners, a
#: procedure and `rig sim` serving the pty: a SET_RATE reply read more than 0.5 s late,
#: bench/bench_kill.py, 2 of 112 runs). A simulated clock does not remove that: the reply
#: is read by this process's thread, on a real rig as against `rig sim --sim-time`
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
#: Hz, the firmware's MAX_RATE_HZ per front end (drivers/firmware/loadcell/loadcell.ino);
#: the fastest build's is the limit of any `[loadcell] rate`
MAX_RATE_HZ = {ADC_HX711: 80, ADC_INA: 1000}
FIRMWARE_MAX_RATE_HZ = max(MAX_RATE_HZ.values())

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
