"""A whole .gspc file as gspc writes and reads it: the typed header, the attribute payloads, the side
information and the bytes each part takes.

A file is parsed and checked once, here: the container (every CRC), the header's records, the side views'
pixels against the file's budget (gspc/limits.py) and each residual image's declared size, before any
camera is built or view rendered. The decoder and ``gspc info`` read the same :class:`GspcFile`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from gspc.format import container
from gspc.format.attribute_section import attribute_chunks, check_attribute_chunks
from gspc.format.chunks import ATTRIBUTE_TYPES, SIDE
from gspc.format.header import FileHeader
from gspc.format.side_chunk import SideViews, read_side_views


@dataclass(frozen=True)
class GspcFile:
    version: tuple[int, int]
    header: FileHeader
    attribute_chunks: dict[str, bytes]  # by type, each checked present and within the count's bound
    side: SideViews
    chunks: tuple[container.Chunk, ...]  # every chunk in file order, unknown optional ones too
    file_size: int
    header_length: int

    @property
    def budget(self) -> dict[str, int]:
        """Bytes per part: the file, each chunk type (payloads with their padding) and the rest (preamble,
        msgpack header, padding, trailer)."""
        return byte_budget(self.file_size, self.chunks)


def byte_budget(file_size: int, chunks: Sequence[container.Chunk]) -> dict[str, int]:
    """Bytes per part of a file of ``file_size`` bytes holding ``chunks`` (see GspcFile.budget)."""
    budget = {"file": file_size}
    for c in chunks:
        budget[c.type] = budget.get(c.type, 0) + container.stored_size(c)
    budget["header+framing"] = file_size - sum(v for k, v in budget.items() if k != "file")
    return budget


def read_file(data: bytes) -> GspcFile:
    """Unpack and check everything a decode uses (FormatError or CodecError, one line, otherwise)."""
    c = container.unpack(data)
    header = FileHeader.from_dict(c.header)
    side = read_side_views(header.side_info.legacy_views, c.chunks, len(data))
    chunks = attribute_chunks(c.chunks)
    check_attribute_chunks(chunks, header.attributes)
    return GspcFile(c.version, header, chunks, side, (*c.chunks, *c.skipped), c.file_size, c.header_length)


def file_chunks(attributes: dict[str, bytes], side: bytes | None) -> list[container.Chunk]:
    """A file's chunks: the attribute chunks in the order the format lists them, then the side information
    in one SIDE chunk (spec 10.9), all required."""
    chunks = [container.Chunk(t, attributes[t]) for t in ATTRIBUTE_TYPES if t in attributes]
    if side is not None:
        chunks.append(container.Chunk(SIDE, side))
    return chunks


def pack_file(header: FileHeader, attributes: dict[str, bytes], side: bytes | None) -> bytes:
    """The file of these parts (:func:`file_chunks`)."""
    return container.pack(header.to_dict(), file_chunks(attributes, side))
