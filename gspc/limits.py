"""Every stated limit on what an input (a .gspc file, a camera file, a SOG archive, an option) may ask for.

A file is untrusted input: each cost it can make gspc pay is checked against a number here before any work
or allocation (issue 15), so the spec can cite one list. Each limit says why it is that number.
"""

from __future__ import annotations

# --- decoding a .gspc file --------------------------------------------------------------------------------

# Refinement iterations a header (side_info.refine_iterations) or --iterations / --check-iterations may ask
# for. The presets use 300 and 1000 (gspc/presets.py); 100x the larger is about 4.4 h for the 20k-Gaussian
# lego fit at 0.16 s per iteration (bench/pipeline.md), far past the point where more iterations gain
# anything (3000: +0.2 dB over 1000).
MAX_REFINE_ITERATIONS = 100_000

# Width and height of any camera, in pixels: the SIDE chunk's per-side limit (gspc/format/side_chunk.py,
# 1..65536), and far beyond any sensor; a camera file's larger sizes are refused rather than scaled.
MAX_CAMERA_SIDE = 1 << 16

# Pixels of one side-information view the decoder renders: 4096 x 4096. Each pixel costs 24 bytes held
# for the whole decode (the render and its restored target, float32 RGB) plus the renderer's work.
MAX_VIEW_PIXELS = 1 << 24

# Pixels of all side-information views together, whatever the file's size: 2^28 is 6 GiB of renders and
# targets, the most a decoder on a workstation should be asked to hold.
MAX_TOTAL_PIXELS = 1 << 28

# ... and bounded by the file's size: at most max(PIXEL_FLOOR, PIXELS_PER_FILE_BYTE * file bytes). A view
# without a residual costs 52 bytes of SIDE chunk (gspc/format/side_chunk.py), so without this rule a 1 KB
# file could ask for 2^28 pixels. The floor admits the default encode of a scene without cameras (24
# synthesised views at 400 x 400 = 3.84 Mpixel, gspc/options.py) whatever the file's size; 1024 pixels per
# byte is 5x the densest real file we have (lego at the low preset: 35 views of 200 x 200 in 199 KB is
# 7 pixels per byte; 120 views of 400 x 267 in 250 KB would be 200).
PIXEL_FLOOR = 1 << 22
PIXELS_PER_FILE_BYTE = 1024


def view_pixel_budget(file_size: int) -> int:
    """The most pixels a .gspc file of ``file_size`` bytes may ask the decoder to render over all views."""
    return min(MAX_TOTAL_PIXELS, max(PIXEL_FLOOR, PIXELS_PER_FILE_BYTE * file_size))


# --- SOG archives (gspc/io/sog.py) -------------------------------------------------------------------------

# Uncompressed size of one member, read from the zip's central directory before the member is read. A SOG
# map of 2^26 Gaussians (the pixel cap below) is at most 256 MiB even as raw RGBA; meta.json is kilobytes.
MAX_SOG_MEMBER_BYTES = 1 << 28
# meta.json: counts, file names and 256-entry codebooks, about 30 KB; 1 MiB is 30x that.
MAX_SOG_META_BYTES = 1 << 20
# A zip member may expand at most this much over its compressed size (above a floor): SOG's maps are WebP,
# already compressed, so deflate gains little on them (and JSON about 3-5x); a member that claims more is a
# decompression bomb, refused before it is inflated.
SOG_MAX_MEMBER_RATIO = 32
SOG_MEMBER_FLOOR = 1 << 16

# Pixels of one decoded SOG WebP map (4 bytes each): 2^26 Gaussians, beyond the largest public 3DGS scenes
# (about 6M Gaussians), and a quarter of WebP's own 16383 x 16383.
MAX_SOG_MAP_PIXELS = 1 << 26

# ... and a map's declared size must fit what it holds (meta.json's count, or the SH palette): one entry per
# pixel, with each side padded by the writer (to a multiple of 4 in splat-transform, to a power of two in
# texture-minded writers: under 2 x 2 = 4 pixels per entry), and a floor for tiny scenes.
SOG_PIXELS_PER_ENTRY = 4
SOG_MAP_FLOOR = 1 << 16

# --- options (gspc/options.py EncodeOptions / DecodeOptions) -----------------------------------------------

# --lambda: the attribute codec's rate knob multiplies quantiser steps; search_lambda
# (gspc/codec/attributes.py) searches 1e-3..1e3, so the same range is accepted from the command line.
MIN_LAMBDA = 1e-3
MAX_LAMBDA = 1e3

# --max-side: side-information views smaller than this have too few pixels for a residual to carry
# anything and for the restorer's 16-pixel blocks (gspc/restore/nafnet.py).
MIN_MAX_SIDE = 16

# --target-size: the container's fixed framing (preamble, header with the attribute metadata, trailer) is
# already about 400 bytes; an attribute bitstream smaller than this cannot be aimed for.
MIN_TARGET_SIZE = 1024

# --views (synthesised cameras): at least one; more than this is hours of rendering for no measured gain.
MAX_SYNTH_VIEWS = 10_000
