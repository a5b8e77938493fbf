"""Differentiable rendering of a GaussianScene from a Camera.

``render(scene, camera)`` is the only entry point the rest of gspc uses. Backends share one
convention (OpenCV camera, INRIA 3DGS projection and compositing: the renderer rules of spec 10.12, which
gsplat 1.5.x departs from by a stated bound, gsplat_backend.py):
- ``"torch"``: gspc's own tile renderer on the scene's device: projection and compositing compiled for the
  CPU (numba), in pure PyTorch elsewhere;
- ``"gsplat"``: gsplat's CUDA rasteriser, only for CUDA tensors when gsplat is installed;
- ``"auto"``: gsplat for CUDA tensors where its kernels run (probed once per process), else torch.
"""

from gspc.render.api import RenderResult, render

__all__ = ["RenderResult", "render"]
