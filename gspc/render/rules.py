"""The compositing rules every render backend shares (spec 10.8, "Rendering convention"): INRIA 3DGS's and
gsplat's. The torch backend (project.py, rasterize.py), the reference (reference.py) and the gsplat backend
take their constants from here."""

from __future__ import annotations

NEAR = 0.01  # Gaussians whose centre has camera z <= NEAR are culled
LOWPASS = 0.3  # added to the 2D covariance diagonal (3DGS's screen-space low-pass filter; gsplat's eps2d)
ALPHA_MIN = 1.0 / 255.0  # contributions below this alpha are skipped
ALPHA_MAX = 0.99  # a Gaussian's alpha is capped here
T_MIN = 1e-4  # a pixel stops before the Gaussian that would take its transmittance below this
