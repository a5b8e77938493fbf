"""gspc: a codec for 3D Gaussian Splatting scenes.

The public names below are imported on first use (PEP 562), so ``import gspc.format.container`` and the
command line's ``--help`` and ``info FILE.gspc`` do not pay for torch (bench/startup.md).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

# public name -> the module that holds it
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
    "render": "gspc.render",
    "GaussianScene": "gspc.scene",
}

__all__ = [
    "Camera",
    "DecodeOptions",
    "EncodeOptions",
    "GaussianScene",
    "GspcError",
    "__version__",
    "decode",
    "decode_bytes",
    "encode",
    "encode_scene",
    "load_cameras",
    "read_scene",
    "render",
    "synthesize_views",
    "write_ply",
]

if TYPE_CHECKING:  # static checkers see the names directly
    from gspc.cameras import Camera
    from gspc.errors import GspcError
    from gspc.io import read_scene, write_ply
    from gspc.io.camera_files import load_cameras
    from gspc.options import DecodeOptions, EncodeOptions
    from gspc.pipeline import decode, decode_bytes, encode, encode_scene
    from gspc.render import render
    from gspc.scene import GaussianScene
    from gspc.views import synthesize_views


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'gspc' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
