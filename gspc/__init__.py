"""gspc: a codec for 3D Gaussian Splatting scenes."""

__version__ = "0.1.0"

from gspc.cameras import Camera, load_cameras, synthesize_views  # noqa: E402
from gspc.errors import GspcError  # noqa: E402
from gspc.io import read_scene, write_ply  # noqa: E402
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode  # noqa: E402
from gspc.render import render  # noqa: E402
from gspc.scene import GaussianScene  # noqa: E402

__all__ = [
    "Camera",
    "DecodeOptions",
    "EncodeOptions",
    "GaussianScene",
    "GspcError",
    "__version__",
    "decode",
    "encode",
    "load_cameras",
    "read_scene",
    "render",
    "synthesize_views",
    "write_ply",
]
