"""The bytes of a .gspc file and every record read out of them, each checked once where it is read:
the container's framing (container.py: typed, versioned, checksummed chunks), the registry of chunk types
(chunks.py), the typed header (header.py) with the attribute codec's section (attribute_section.py), the
side-information views (view_records.py; side_chunk.py reads both layouts) and the sizes their residual
images declare (image_headers.py). Nothing here imports a codec: gspc/codec/ reads these records."""
