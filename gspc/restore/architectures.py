"""Restorer architectures by the name a weights manifest gives them (``"architecture"``, spec-free: the
manifest is the package's own, gspc/restore/weights/MANIFEST.json). A new architecture is a module with an
``nn.Module`` built from keyword arguments, registered here."""

from __future__ import annotations

from torch import nn

from gspc.errors import CodecError
from gspc.restore.nafnet import NAFNet

ARCHITECTURES: dict[str, type[nn.Module]] = {"nafnet": NAFNet}
# A manifest entry that names no architecture is a NAFNet (the registry's first architecture).
DEFAULT_ARCHITECTURE = "nafnet"


def build(architecture: str, config: dict, name: str) -> nn.Module:
    """An untrained model of ``architecture`` with ``config``; CodecError for an unknown one."""
    if architecture not in ARCHITECTURES:
        raise CodecError(
            f"restorer {name!r} names architecture {architecture!r}; gspc has {', '.join(ARCHITECTURES)}"
        )
    return ARCHITECTURES[architecture](**config)
