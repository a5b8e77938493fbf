"""The bytes of a .gspc file: the container's framing (container.py: typed, versioned, checksummed chunks),
the typed header (header.py) and the registry of chunk types (chunks.py). Nothing here knows a codec."""
