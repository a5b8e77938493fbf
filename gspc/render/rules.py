"""The file's renderer rules (spec 10.12): part of the decoder's definition, INRIA 3DGS's. The torch backend
(project.py, rasterize.py) and the reference (reference.py) follow them and take their constants from here;
the gsplat backend passes NEAR and LOWPASS to gsplat, whose 1.5.x kernels cap alpha at 0.999 instead of
ALPHA_MAX and skip q < 0 (gsplat_backend.py says by how much that misses)."""

from __future__ import annotations

NEAR = 0.01  # Gaussians whose centre has camera z <= NEAR are culled
LOWPASS = 0.3  # added to the 2D covariance diagonal (3DGS's screen-space low-pass filter; gsplat's eps2d)
ALPHA_MIN = 1.0 / 255.0  # contributions below this alpha are skipped
ALPHA_MAX = 0.99  # a Gaussian's alpha is capped here
T_MIN = 1e-4  # a pixel stops before the Gaussian that would take its transmittance below this
