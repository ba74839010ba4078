"""ROS 2's wire format: OMG CDR (XCDR1, "DDS_CDR", what rmw_zenoh and DDS send) with its
4-byte encapsulation header, little- or big-endian, for the few message types the bridge
needs (msgs.py). Pure: bytes in, numbers out.

The header is 0x00 0x01 (little-endian) or 0x00 0x00 (big-endian), then two option bytes.
Every primitive is aligned to its own size (8 at most), counted from the end of the header;
a string is a uint32 length (with its NUL), its bytes and the NUL; a sequence a uint32 count
and its elements; a fixed array its elements alone.
"""

from __future__ import annotations

import struct

import numpy as np

HEADER_LE = b"\x00\x01\x00\x00"
HEADER_BE = b"\x00\x00\x00\x00"
MAX_SEQUENCE = 1_000_000  # elements: a scan has thousands at most; more is a corrupt count
_FORMATS = {"int32": "i", "uint32": "I", "float32": "f", "float64": "d"}


class CdrError(ValueError):
    """Bytes that are not the expected message; says where and why."""


class CdrReader:
    """Reads one message's fields in order from its serialized bytes (header included)."""

    def __init__(self, data: bytes | memoryview, what: str) -> None:
        self.data = bytes(data)
        self.what = what
        if len(self.data) < 4:
            raise CdrError(f"{what}: {len(self.data)} bytes, shorter than the CDR header")
        kind = self.data[:2]
        if kind not in (HEADER_LE[:2], HEADER_BE[:2]):
            raise CdrError(
                f"{what}: encapsulation {kind.hex()} is not plain CDR (0000 big-endian, "
                "0001 little-endian): XCDR2 or a parameter list is not supported"
            )
        self.little = kind == HEADER_LE[:2]
        self.order = "<" if self.little else ">"
        self.pos = 4

    def _take(self, size: int, align: int) -> int:
        body = self.pos - 4
        self.pos += (-body) % align
        start = self.pos
        if start + size > len(self.data):
            raise CdrError(f"{self.what}: ends after {len(self.data)} bytes, needs {start + size}")
        self.pos = start + size
        return start

    def primitive(self, kind: str) -> float | int:
        fmt = _FORMATS[kind]
        size = struct.calcsize(fmt)
        (value,) = struct.unpack_from(self.order + fmt, self.data, self._take(size, size))
        return value

    def string(self) -> str:
        length = int(self.primitive("uint32"))
        if length == 0:  # some writers send an empty string as a zero length
            return ""
        start = self._take(length, 1)
        raw = self.data[start : start + length]
        if raw[-1:] != b"\x00":
            raise CdrError(f"{self.what}: a string of {length} bytes lacks its NUL")
        try:
            return raw[:-1].decode("utf-8")
        except UnicodeDecodeError as e:
            raise CdrError(f"{self.what}: a string is not UTF-8: {e}") from None

    def float32_sequence(self) -> np.ndarray:
        count = int(self.primitive("uint32"))
        if count > MAX_SEQUENCE:
            raise CdrError(f"{self.what}: a sequence of {count} elements (at most {MAX_SEQUENCE})")
        if count == 0:
            return np.zeros(0, np.float32)
        start = self._take(4 * count, 4)
        return np.frombuffer(self.data, self.order + "f4", count, start).astype(np.float32)

    def float64_array(self, count: int) -> np.ndarray:
        start = self._take(8 * count, 8)
        return np.frombuffer(self.data, self.order + "f8", count, start).astype(np.float64)

    def end(self) -> None:
        """Only alignment padding may follow the last field."""
        rest = len(self.data) - self.pos
        if rest > 3:
            raise CdrError(f"{self.what}: {rest} bytes after the last field")


class CdrWriter:
    """Writes a message's fields in order; `bytes()` is the serialized message."""

    def __init__(self, little_endian: bool = True) -> None:
        self.order = "<" if little_endian else ">"
        self.out = bytearray(HEADER_LE if little_endian else HEADER_BE)

    def _align(self, align: int) -> None:
        self.out += b"\x00" * ((-(len(self.out) - 4)) % align)

    def primitive(self, kind: str, value: float) -> None:
        fmt = _FORMATS[kind]
        self._align(struct.calcsize(fmt))
        self.out += struct.pack(self.order + fmt, value)

    def string(self, text: str) -> None:
        raw = text.encode("utf-8") + b"\x00"
        self.primitive("uint32", len(raw))
        self.out += raw

    def float32_sequence(self, values: np.ndarray) -> None:
        array = np.asarray(values, dtype=self.order + "f4")
        self.primitive("uint32", len(array))
        if len(array):
            self._align(4)
            self.out += array.tobytes()

    def float64_array(self, values: np.ndarray, count: int) -> None:
        array = np.asarray(values, dtype=self.order + "f8")
        if array.shape != (count,):
            raise CdrError(f"a fixed array of {count} float64 got shape {array.shape}")
        self._align(8)
        self.out += array.tobytes()

    def __bytes__(self) -> bytes:
        return bytes(self.out)
