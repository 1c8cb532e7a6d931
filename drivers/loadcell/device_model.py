"""What the load-cell firmware does with each command: the device model its fakes share."""

from __future__ import annotations

import random
import time
from typing import Callable

from drivers.loadcell.protocol import (ADC_INA, CMD_IDENTIFY, CMD_SET_RATE, CMD_START, CMD_STATUS, CMD_STOP, CMD_TARE,
                                       COMMAND_PAYLOAD_LEN, ERR_BAD_ARGUMENT, ERR_BAD_CRC, ERR_BAD_LENGTH, ERR_BUSY,
                                       ERR_INCOMPLETE, ERR_UNKNOWN_COMMAND, ERROR_FMT, FIRMWARE_VERSION,
                                       PROTOCOL_VERSION, RATE_FMT, REPLY, SAMPLE_SATURATED, STATUS_SATURATED,
                                       STATUS_STREAMING, STATUS_TARE_BUSY, T_ERROR, TARE_CMD_FMT, TARE_REPLY_FMT,
                                       Identity, RawSample, Status, identity_payload, status_payload)


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
