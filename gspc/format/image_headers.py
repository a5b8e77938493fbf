"""Image sizes read from the headers of residual images (JPEG XL, WebP, AVIF) without decoding them: a
residual's codestream may declare a huge size, which decoding would allocate unchecked (issue 15), so a
file's images are measured here first (gspc/format/side_chunk.py), and so are SOG's WebP maps
(gspc/io/sog.py). Written from the codecs' specifications; no image library is needed.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from gspc.errors import CodecError

_JXL_RATIOS = {1: (1, 1), 2: (12, 10), 3: (4, 3), 4: (3, 2), 5: (16, 9), 6: (5, 4), 7: (2, 1)}
_JXL_CONTAINER = b"\x00\x00\x00\x0cJXL \r\n\x87\n"


class _Bits:
    """JPEG XL's bit reader: least significant bit of each byte first."""

    def __init__(self, data: bytes):
        self.data, self.pos = data, 0

    def read(self, n: int) -> int:
        v = 0
        for i in range(n):
            byte = self.pos >> 3
            if byte >= len(self.data):
                raise CodecError("residual jxl codestream ends inside its size header")
            v |= ((self.data[byte] >> (self.pos & 7)) & 1) << i
            self.pos += 1
        return v

    def u32_size(self) -> int:
        """U32(Bits(9) + 1, Bits(13) + 1, Bits(18) + 1, Bits(30) + 1), the SizeHeader's distribution."""
        return self.read((9, 13, 18, 30)[self.read(2)]) + 1


def _jxl_codestream(data: bytes) -> bytes:
    """The codestream of a bare JPEG XL stream or of the ISOBMFF container's first jxlc/jxlp box."""
    if not data.startswith(_JXL_CONTAINER):
        return data
    pos = 0
    while pos + 8 <= len(data):
        size, kind = struct.unpack_from(">I4s", data, pos)
        head = 8
        if size == 1 and pos + 16 <= len(data):
            (size,) = struct.unpack_from(">Q", data, pos + 8)
            head = 16
        end = len(data) if size == 0 else pos + size
        if kind == b"jxlc":
            return data[pos + head : end]
        if kind == b"jxlp":
            return data[pos + head + 4 : end]  # after the part index
        if size < head:
            break
        pos = end
    raise CodecError("residual jxl container holds no codestream box")


def _jxl_size(data: bytes) -> tuple[int, int]:
    """(width, height) from the SizeHeader that follows the codestream signature FF 0A."""
    code = _jxl_codestream(data)
    if code[:2] != b"\xff\x0a":
        raise CodecError("residual jxl payload does not start with a JPEG XL signature")
    b = _Bits(code[2:34])
    small = b.read(1)
    height = (b.read(5) + 1) * 8 if small else b.u32_size()
    ratio = b.read(3)
    if ratio:
        num, den = _JXL_RATIOS[ratio]
        width = height * num // den
    else:
        width = (b.read(5) + 1) * 8 if small else b.u32_size()
    return width, height


def _webp_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a WebP's first chunk: VP8 (lossy), VP8L (lossless) or VP8X (extended)."""
    if len(data) < 30 or data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        raise CodecError("residual webp payload is not a RIFF WEBP file")
    kind, body = data[12:16], data[20:30]
    if kind == b"VP8 " and body[3:6] == b"\x9d\x01\x2a":
        w, h = struct.unpack_from("<HH", body, 6)
        return w & 0x3FFF, h & 0x3FFF
    if kind == b"VP8L" and body[0] == 0x2F:
        (bits,) = struct.unpack_from("<I", body, 1)
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind == b"VP8X":
        w = int.from_bytes(body[4:7], "little") + 1
        h = int.from_bytes(body[7:10], "little") + 1
        return w, h
    raise CodecError(f"residual webp payload has no size header (first chunk {kind!r})")


def _avif_size(data: bytes) -> tuple[int, int]:
    """The largest (width, height) of the image spatial extents (ispe) in meta/iprp/ipco."""

    def boxes(buf: bytes, start: int, end: int):
        pos = start
        while pos + 8 <= end:
            size, kind = struct.unpack_from(">I4s", buf, pos)
            head = 8
            if size == 1 and pos + 16 <= end:
                (size,) = struct.unpack_from(">Q", buf, pos + 8)
                head = 16
            size = end - pos if size == 0 else size
            if size < head or pos + size > end:
                return
            yield kind, pos + head, pos + size
            pos += size

    sizes = []
    for kind, a, b in boxes(data, 0, len(data)):
        if kind != b"meta":
            continue
        for kind2, a2, b2 in boxes(data, a + 4, b):  # meta is a full box: 4 bytes version and flags
            if kind2 != b"iprp":
                continue
            for kind3, a3, b3 in boxes(data, a2, b2):
                if kind3 != b"ipco":
                    continue
                for kind4, a4, b4 in boxes(data, a3, b3):
                    if kind4 == b"ispe" and b4 - a4 >= 12:
                        sizes.append(struct.unpack_from(">II", data, a4 + 4))
    if not sizes:
        raise CodecError("residual avif payload has no image size (ispe) box")
    return max(w for w, _ in sizes), max(h for _, h in sizes)


SIZE_READERS: dict[str, Callable[[bytes], tuple[int, int]]] = {
    "jxl": _jxl_size,
    "webp": _webp_size,
    "avif": _avif_size,
}


def coded_size(codec: str, payload: bytes) -> tuple[int, int]:
    """(width, height) that an image's header declares, without decoding it; CodecError if none."""
    if codec not in SIZE_READERS:
        raise CodecError(f"residual image codec {codec!r} is not one gspc reads")
    try:
        return SIZE_READERS[codec](bytes(payload))
    except (struct.error, IndexError, KeyError):
        raise CodecError(f"residual {codec} payload ends inside its size header") from None
