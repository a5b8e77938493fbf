"""The file's renderer rules (spec 10.12): part of the decoder's definition, INRIA 3DGS's. The torch backend
(project.py, rasterize.py), its compiled CPU kernels (project_cpu.py, composite_cpu.py) and the reference
(reference.py) follow them and take their constants from here; the gsplat backend passes NEAR and LOWPASS to
gsplat, whose 1.5.x kernels cap alpha at 0.999 instead of ALPHA_MAX and skip q < 0 (gsplat_backend.py says by
how much that misses)."""

from __future__ import annotations

NEAR = 0.01  # Gaussians whose centre has camera z <= NEAR are culled
LOWPASS = 0.3  # added to the 2D covariance diagonal (3DGS's screen-space low-pass filter; gsplat's eps2d)
ALPHA_MIN = 1.0 / 255.0  # contributions below this alpha are skipped
ALPHA_MAX = 0.99  # a Gaussian's alpha is capped here
T_MIN = 1e-4  # a pixel stops before the Gaussian that would take its transmittance below this

# How the torch backend culls (not part of the image: any culling that keeps every pixel whose alpha reaches
# ALPHA_MIN gives the same image). Pixels are walked in TILE x TILE tiles, each with a list of the Gaussians
# whose alpha >= 1/255 ellipse, q <= 2 ln(255 o), reaches one of its pixel centres (rasterize.py bin_tiles).
TILE = 8
PIXELS = TILE * TILE
# The ellipse's box and its tile test are widened slightly so that round-off in the compositor's alpha never
# reaches past them: half-extents by this fraction plus this many pixels.
EXTENT_REL_MARGIN = 1e-3
EXTENT_ABS_MARGIN = 1e-2
# The compiled compositor walks the ellipse q <= thr (1 + this) + this, thr = 2 ln(255 o), and the tile test
# lists the tiles of that ellipse.
THRESHOLD_REL_MARGIN = 1e-6
