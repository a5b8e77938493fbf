"""gspc: a codec for 3D Gaussian Splatting scenes."""

from gspc.cameras import Camera
from gspc.errors import GspcError
from gspc.scene import GaussianScene

__version__ = "0.1.0"

__all__ = ["Camera", "GaussianScene", "GspcError", "__version__"]
