"""Frames out of a byte stream: resynchronised on SYNC, length and CRC checked, rejects counted."""

from __future__ import annotations

from typing import Callable

from drivers.loadcell.protocol import FRAME_OVERHEAD, KNOWN_TYPES, MAX_PAYLOAD, SYNC, Frame, crc16_ccitt_false


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
