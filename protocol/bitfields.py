"""Vectorised encode/decode of DBC-style signals on blocks of frames (numpy), from cantools' or canopen's
own signal descriptions.

cantools decodes one frame at a time (tens of µs each); a robot bus carries thousands of frames per
second and a 200-cycle recording tens of millions. :class:`BitField` holds what decoding a signal needs
(start bit, length, byte order, signedness, scale, offset) and works on a block: ``data`` (n, 8) uint8.
``BitField.from_cantools(signal)`` takes cantools' numbering (Intel: start = LSB; Motorola: start = MSB
in the DBC's sawtooth numbering), so a field decodes exactly what ``Message.decode`` decodes
(tests/test_bitfields.py checks both directions against cantools with hypothesis).
Floating-point signals are refused with a clear error (no robot signal we met needs them). Physical values
are float64: exact for raw values up to 2⁵³ (encoding saturates unsigned fields at 2⁶³).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

_LITTLE = "little_endian"
_BIG = "big_endian"


class BitFieldError(ValueError):
    """A signal that this codec cannot handle (the message names it and says why)."""


@dataclass(frozen=True)
class BitField:
    """One signal's place in an 8-byte frame and its linear scaling: value = raw · scale + offset.

    ``start``: cantools' start bit (Intel: the least significant bit; Motorola: the most significant bit
    in the DBC sawtooth numbering, bit 7 of byte 0 is 7, bit 0 of byte 1 is 8).
    """

    name: str
    start: int
    length: int
    byte_order: str = _LITTLE
    signed: bool = False
    scale: float = 1.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        if self.byte_order not in (_LITTLE, _BIG):
            raise BitFieldError(f"signal {self.name}: byte order must be {_LITTLE} or {_BIG}, got {self.byte_order}")
        if not 1 <= self.length <= 64:
            raise BitFieldError(f"signal {self.name}: length must be 1 … 64 bits, got {self.length}")
        if not 0 <= self.start < 64 or self._shift() < 0 or self.end_byte > 8:
            raise BitFieldError(f"signal {self.name}: start bit {self.start}, length {self.length} "
                                f"does not fit in 8 bytes ({self.byte_order})")
        if self.scale == 0:
            raise BitFieldError(f"signal {self.name}: scale must not be 0")

    @classmethod
    def from_cantools(cls, signal: Any) -> "BitField":
        if getattr(signal, "is_float", False):
            raise BitFieldError(f"signal {signal.name}: floating-point signals are not supported; "
                                "map an integer signal instead")
        return cls(name=signal.name, start=int(signal.start), length=int(signal.length),
                   byte_order=str(signal.byte_order), signed=bool(signal.is_signed),
                   scale=float(signal.scale), offset=float(signal.offset))

    # ------------------------------------------------------------------ geometry
    def _msb_position(self) -> int:
        """Big-endian stream position (0 = MSB of byte 0) of the most significant bit."""
        return (self.start // 8) * 8 + (7 - self.start % 8)

    def _shift(self) -> int:
        """Right shift of the frame's 64-bit word (little-endian word for Intel, big-endian for Motorola)."""
        if self.byte_order == _LITTLE:
            return self.start if self.start + self.length <= 64 else -1
        return 64 - self._msb_position() - self.length

    @property
    def end_byte(self) -> int:
        """Bytes a frame needs to carry the whole signal (its DLC at least)."""
        if self.byte_order == _LITTLE:
            return (self.start + self.length - 1) // 8 + 1
        return (self._msb_position() + self.length - 1) // 8 + 1

    def _mask(self) -> np.uint64:
        return np.uint64(0xFFFF_FFFF_FFFF_FFFF) if self.length == 64 else np.uint64((1 << self.length) - 1)

    # ------------------------------------------------------------------ codec
    def raw(self, data: NDArray[np.uint8]) -> NDArray[np.int64] | NDArray[np.uint64]:
        """Raw integer of each row (two's complement applied for signed signals)."""
        word = _words(data, self.byte_order)
        raw = (word >> np.uint64(self._shift())) & self._mask()
        if not self.signed:
            return raw
        spare = np.uint64(64 - self.length)            # sign-extend: to the top, arithmetic shift back
        return (raw << spare).view(np.int64) >> np.int64(64 - self.length)

    def decode(self, data: NDArray[np.uint8]) -> NDArray[np.float64]:
        """Physical value of each row (raw · scale + offset)."""
        return self.raw(data).astype(np.float64) * self.scale + self.offset

    def raw_limits(self) -> tuple[int, int]:
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1

    def encode_into(self, data: NDArray[np.uint8], values: NDArray[np.float64] | float) -> None:
        """Write ``values`` (physical, rounded to the step, saturated to the field) into ``data`` in place."""
        lo, hi = self.raw_limits()
        raw = np.clip(np.rint((np.asarray(values, dtype=np.float64) - self.offset) / self.scale),
                      float(lo), float(min(hi, (1 << 63) - 1024)))
        self.encode_raw_into(data, raw.astype(np.int64))

    def encode_raw_into(self, data: NDArray[np.uint8], raw: NDArray[np.int64] | int) -> None:
        """Write raw integers into ``data`` (n, 8) in place (other bits kept)."""
        mask = self._mask()
        bits = (np.broadcast_to(np.asarray(raw, dtype=np.int64), (data.shape[0],)).view(np.uint64) & mask)
        shift = np.uint64(self._shift())
        word = _words(data, self.byte_order)
        word = (word & ~(mask << shift)) | (bits << shift)
        dtype = "<u8" if self.byte_order == _LITTLE else ">u8"
        data[:] = word.astype(dtype).view(np.uint8).reshape(-1, 8)


def _words(data: NDArray[np.uint8], byte_order: str) -> NDArray[np.uint64]:
    """Each row's 8 bytes as one unsigned 64-bit integer (little- or big-endian)."""
    rows = np.ascontiguousarray(data, dtype=np.uint8).reshape(-1, 8)
    dtype = "<u8" if byte_order == _LITTLE else ">u8"
    return rows.view(dtype).reshape(-1).astype(np.uint64)


@dataclass(frozen=True)
class ResolvedSignal:
    """A DBC signal found by name: its frame, bit field, if multiplexed the multiplexer and its value, and the
    unit the DBC gives it ("" when none)."""

    message: str
    frame_id: int
    bits: BitField
    mux: BitField | None = None
    mux_value: int = 0
    unit: str = ""


def resolve(db: Any, message_name: str | None, signal_name: str | None) -> ResolvedSignal:
    """Find ``message_name.signal_name`` in a cantools database; :class:`BitFieldError` names the nearest
    messages or the message's signals when it is not there."""
    import difflib
    try:
        message = db.get_message_by_name(message_name)
    except KeyError:
        near = difflib.get_close_matches(str(message_name), [m.name for m in db.messages], n=3)
        raise BitFieldError(f"message {message_name!r} is not in the DBC"
                            + (f" (did you mean {', '.join(near)}?)" if near else "")) from None
    signal = next((s for s in message.signals if s.name == signal_name), None)
    if signal is None:
        raise BitFieldError(f"message {message.name} has no signal {signal_name!r}; it has "
                            f"{[s.name for s in message.signals]}")
    mux, value = None, 0
    if signal.multiplexer_ids:
        mux_signal = next(s for s in message.signals if s.name == signal.multiplexer_signal)
        mux, value = BitField.from_cantools(mux_signal), int(signal.multiplexer_ids[0])
    return ResolvedSignal(message.name, int(message.frame_id), BitField.from_cantools(signal), mux, value,
                          str(signal.unit or "").strip())
