"""gspc: a codec for 3D Gaussian Splatting scenes.

The public names below are imported on first use (PEP 562), so ``import gspc.format.container`` and the
command line's ``--help`` and ``info FILE.gspc`` do not pay for torch (bench/startup.md).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# The public API: name -> the module that holds it. __all__ follows from it, and the TYPE_CHECKING imports
# below must name the same (tests/test_public_api.py ties the three together).
_LAZY = {
    "Camera": "gspc.cameras",
    "load_cameras": "gspc.io.camera_files",
    "synthesize_views": "gspc.views",
    "GspcError": "gspc.errors",
    "read_scene": "gspc.io",
    "write_ply": "gspc.io",
    "DecodeOptions": "gspc.options",
    "EncodeOptions": "gspc.options",
    "decode": "gspc.pipeline",
    "decode_bytes": "gspc.pipeline",
    "encode": "gspc.pipeline",
    "encode_scene": "gspc.pipeline",
    "decode_tiles": "gspc.pipeline",
    "DecodedTile": "gspc.pipeline",
    # Not "render": importing the subpackage gspc.render binds that name to the module.
    "render_view": "gspc.render:render",
    "GaussianScene": "gspc.scene",
}

__all__ = sorted([*_LAZY, "__version__"])

if TYPE_CHECKING:  # static checkers see the names directly (``as``: re-exported)
    from gspc.cameras import Camera as Camera
    from gspc.errors import GspcError as GspcError
    from gspc.io import read_scene as read_scene
    from gspc.io import write_ply as write_ply
    from gspc.io.camera_files import load_cameras as load_cameras
    from gspc.options import DecodeOptions as DecodeOptions
    from gspc.options import EncodeOptions as EncodeOptions
    from gspc.pipeline import DecodedTile as DecodedTile
    from gspc.pipeline import decode as decode
    from gspc.pipeline import decode_bytes as decode_bytes
    from gspc.pipeline import decode_tiles as decode_tiles
    from gspc.pipeline import encode as encode
    from gspc.pipeline import encode_scene as encode_scene
    from gspc.render import render as render_view  # noqa: F401  (re-exported under another name)
    from gspc.scene import GaussianScene as GaussianScene
    from gspc.views import synthesize_views as synthesize_views


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'gspc' has no attribute {name!r}")
    module, _, attr = _LAZY[name].partition(":")  # "module:attr" where the names differ
    value = getattr(importlib.import_module(module), attr or name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
