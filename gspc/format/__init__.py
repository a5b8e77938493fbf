"""The .gspc file's own structure above the container: the typed header (header.py) and the registry of
chunk types (chunks.py). The byte framing itself is gspc/codec/container.py."""
