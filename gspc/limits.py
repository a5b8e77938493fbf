"""Every stated limit on what an input (a .gspc file, a camera file, a SOG archive, an option) may ask for.

A file is untrusted input: each cost it can make gspc pay is checked against a number here before any work
or allocation (issue 15), so the spec can cite one list. Each limit says why it is that number.
"""

from __future__ import annotations

from dataclasses import dataclass

# --- decoding a .gspc file --------------------------------------------------------------------------------
# The measurements behind the per-byte rules (what real files of each kind ask for, and the work and memory of
# files crafted at each limit) are in bench/robustness.md: "What real files ask of a decoder" and "Work asked
# for by files at each size-bounded limit".

# Refinement iterations a header (side_info.refine_iterations) or --iterations / --check-iterations may ask
# for: far past the presets' (gspc/presets.py) and past the point where more iterations gain anything
# (bench/refine.md).
MAX_REFINE_ITERATIONS = 100_000
# The encoder's tuning of its coded values (gspc/encoder/tuning.py): each iteration codes the scene once.
MAX_TUNE_ITERATIONS = 1_000

# The header's refine_iterations is the decoder's DEFAULT refinement (no --iterations given), and a file may
# not make that default longer than its Gaussians warrant: at most max(REFINE_DEFAULT_FLOOR, n) iterations
# for n coded Gaussians (an iteration costs a few milliseconds whatever the scene, issue 26). The decoder's
# work budget below bounds it again by the file's bytes; --iterations asks for any length up to
# MAX_REFINE_ITERATIONS.
REFINE_DEFAULT_FLOOR = 1000


def default_refine_iterations(file_iterations: int, num_gaussians: int) -> int:
    """The refinement a decode runs without --iterations, before the work budget: the file's number,
    bounded by its Gaussians."""
    return min(file_iterations, max(REFINE_DEFAULT_FLOOR, num_gaussians), MAX_REFINE_ITERATIONS)


# Gaussians a .gspc file may declare for its attribute payload bytes P (POSN, OPAC, SCAL, ROTN, SHDC and
# SHRS chunk payloads together): at most max(GAUSSIAN_FLOOR, floor(8 P / MIN_CODED_BITS_PER_GAUSSIAN)). A
# Gaussian whose every symbol has a one-value model costs no bits, so without this rule a tiny file could
# ask for any allocation (issue 26). Real files code about twice this minimum at the coarsest rates; the
# floor keeps any scene of up to 2^16 Gaussians codable however regular (a lattice of identical Gaussians
# codes in almost no bits).
GAUSSIAN_FLOOR = 1 << 16
MIN_CODED_BITS_PER_GAUSSIAN = 12


def max_coded_gaussians(payload_bytes: int) -> int:
    """The most Gaussians attribute payloads of ``payload_bytes`` bytes in all may declare."""
    return max(GAUSSIAN_FLOOR, 8 * payload_bytes // MIN_CODED_BITS_PER_GAUSSIAN)


# Entries of the probability tables one entropy-coded matrix's models build (spec 10.0: a kind-2 or kind-3
# model over lo..hi builds hi - lo + 1), summed over all its models, for a matrix payload of P bytes: at most
# max(MODEL_TABLE_FLOOR, MODEL_ENTRIES_PER_BYTE * P). A six-integer geometric model may span 2^22 symbols, so
# without this rule a few kilobytes could ask for minutes of table building (issue 26). The floor is one
# model of the widest window (gspc/codec/entropy.py MAX_WINDOW), and a file holds at most 8 matrices; at
# attribute codec version 4 (up to 16 classes, a matrix each per chunk) the matrices of one chunk also share
# this bound, P the chunk's bytes (gspc/codec/precision.py unpack_bins), so a file again holds at most 8
# floors' worth. Tables grow as 1/lambda: this rule stops the finest lambdas on real scenes, where the
# encoder refuses with a ValueRangeError (a larger lambda codes it) rather than write a file the decoder
# refuses.
MODEL_TABLE_FLOOR = 1 << 22
MODEL_ENTRIES_PER_BYTE = 16


def max_model_entries(payload_bytes: int) -> int:
    """The most probability-table entries the models of one matrix payload of ``payload_bytes`` may build."""
    return max(MODEL_TABLE_FLOOR, MODEL_ENTRIES_PER_BYTE * payload_bytes)


# Decompressed bytes of one matrix's model list (a zstd frame of msgpack) for a frame of P bytes: at most
# max(MODEL_LIST_FLOOR, MODEL_LIST_RATIO * P), and never beyond MAX_MODELS_BYTES. zstd can expand a frame
# thousands of times, and every decompressed byte is parsed and checked in Python (issue 26); real model
# lists compress a few times at most.
MODEL_LIST_FLOOR = 1 << 16
MODEL_LIST_RATIO = 32
MAX_MODELS_BYTES = 1 << 26


def max_model_list_bytes(frame_bytes: int) -> int:
    """The most bytes a model list's zstd frame of ``frame_bytes`` bytes may decompress to."""
    return min(MAX_MODELS_BYTES, max(MODEL_LIST_FLOOR, MODEL_LIST_RATIO * frame_bytes))


# Width and height of any camera, in pixels: the SIDE chunk's per-side limit (gspc/format/side_chunk.py,
# 1..65536), and far beyond any sensor; a camera file's larger sizes are refused rather than scaled.
MAX_CAMERA_SIDE = 1 << 16

# Pixels of one side-information view the decoder renders: 4096 x 4096. The decoder holds each pixel for the
# whole decode (the render and its restored target) and renders and restores it.
MAX_VIEW_PIXELS = 1 << 24

# Pixels of all side-information views together, whatever the file's size: 2^28 pixels of renders and
# targets are the most a decoder on a workstation should be asked to hold.
MAX_TOTAL_PIXELS = 1 << 28

# ... and bounded by the file's size: at most max(PIXEL_FLOOR, PIXELS_PER_FILE_BYTE * file bytes). A view
# without a residual costs 52 bytes of SIDE chunk (gspc/format/side_chunk.py), so without this rule a 1 KB
# file could ask for 2^28 pixels. The floor admits the default encode of a scene without cameras (24
# synthesised views at 400 x 400, gspc/options.py) whatever the file's size; real files hold a few hundred
# pixels per byte at most.
PIXEL_FLOOR = 1 << 22
PIXELS_PER_FILE_BYTE = 1024


def view_pixel_budget(file_size: int) -> int:
    """The most pixels a .gspc file of ``file_size`` bytes may ask the decoder to render over all views."""
    return min(MAX_TOTAL_PIXELS, max(PIXEL_FLOOR, PIXELS_PER_FILE_BYTE * file_size))


# --- the work of a decoder that renders: restores, refines (spec 10.8, "The decoder's work") --------------

# Gaussian-tile pairs of one render (the boxes' tiles, counted before the compositor allocates its lists:
# gspc/render/rasterize.py bin_tiles): every render, of a file or of a user's own scene, is refused beyond
# this. The lists take a few bytes per pair, so this is gigabytes, far beyond any real view.
MAX_VIEW_PAIRS = 1 << 30

# Pairs of one side-information view of a .gspc file of F bytes: at most max(PAIR_FLOOR, PAIRS_PER_FILE_BYTE
# * F), counted from each view's projection before it is rendered (gspc/render/work.py, spec 10.8). Without
# this rule a 1 KB file of 2^16 identical large Gaussians in front of one view asked the compositor for
# gigabytes (issue 50). Real files hold a few pairs per byte at most in their largest view; the floor admits
# a small scene filling a view of the pixel floor's size.
PAIR_FLOOR = 1 << 22
PAIRS_PER_FILE_BYTE = 32


def view_pair_budget(file_size: int) -> int:
    """The most Gaussian-tile pairs one view of a .gspc file of ``file_size`` bytes may ask for."""
    return min(MAX_VIEW_PAIRS, max(PAIR_FLOOR, PAIRS_PER_FILE_BYTE * file_size))


# The decoder's work, in units of what rendering costs: rendering a view once costs its Gaussians plus its
# pairs plus its pixels (view_work), restoring a pixel RESTORE_PIXEL_WORK units (the restorer is a network
# run over every pixel). A decode that renders does the first renders of every view, restores the views that
# carry a residual and refines, each iteration rendering one view (its cost: the heaviest view's). The first
# renders and the restoration together may cost at most the file's budget, max(WORK_FLOOR,
# WORK_PER_FILE_BYTE * F); beyond, the file is refused. The default refinement runs at most as many
# iterations as the rest of the budget pays for (refine_work_iterations). Without this rule a 1 KB file of
# 2^16 identical Gaussians naming 2^16 iterations asked for hours (issue 50). The floor pays for restoring
# the pixel floor's views (and their renders) whatever the file's size; real files ask for a fraction of the
# per-byte term, and the encoder names no more iterations than its file's budget pays for
# (gspc/reconstruct.py work_bound, gspc/pipeline.py).
WORK_FLOOR = 1 << 26
WORK_PER_FILE_BYTE = 4096
RESTORE_PIXEL_WORK = 8


def view_work(num_gaussians: int, pairs: int, pixels: int) -> int:
    """The work of rendering one view once: its Gaussians, Gaussian-tile pairs and pixels."""
    return num_gaussians + pairs + pixels


def decode_work_budget(file_size: int) -> int:
    """The most work a .gspc file of ``file_size`` bytes may ask of a decoder by default."""
    return max(WORK_FLOOR, WORK_PER_FILE_BYTE * file_size)


def refine_work_iterations(first_work: int, heaviest_view: int, file_size: int | RenderAllowance) -> int:
    """The refinement iterations a file's budget (or a tile's share: :class:`RenderAllowance`) pays for
    after ``first_work`` (its first renders and restoration), each costing ``heaviest_view``."""
    left = allowance(file_size).work - first_work
    return max(0, left) // max(1, heaviest_view)


@dataclass(frozen=True)
class RenderAllowance:
    """What the side views of a file, or of one tile of a tiled file, may ask a decoder for: pixels over
    the views, Gaussian-tile pairs per view and work (spec 10.8). A tile's is its share of one file's floors,
    in proportion to its bytes (spec 10.15), so that a file of many small tiles asks for no more floors than
    one file, while each tile is bounded, and refined, alone."""

    pixels: int
    pairs: int
    work: int
    of: str  # what it belongs to, for refusals: "a 1,024-byte file", "tile 3"
    rule: str  # the rule's words, for refusals

    @classmethod
    def of_file(cls, file_size: int) -> RenderAllowance:
        return cls(
            view_pixel_budget(file_size),
            view_pair_budget(file_size),
            decode_work_budget(file_size),
            f"a {file_size:,}-byte file",
            "spec 10.8",
        )

    @classmethod
    def of_tile(cls, number: int, tile_bytes: int, all_bytes: int, span: int = 1) -> RenderAllowance:
        """Tile ``number``'s share: ``tile_bytes`` its attribute and TSID payloads (its span's, of ``span``
        tiles: spec 10.17), ``all_bytes`` every tile's."""

        def share(floor: int, per_byte: int) -> int:
            return max(floor * tile_bytes // max(all_bytes, 1), per_byte * tile_bytes)

        who = f"tile {number}'s span of {span}" if span > 1 else f"tile {number}"
        return cls(
            min(MAX_TOTAL_PIXELS, share(PIXEL_FLOOR, PIXELS_PER_FILE_BYTE)),
            min(MAX_VIEW_PAIRS, share(PAIR_FLOOR, PAIRS_PER_FILE_BYTE)),
            share(WORK_FLOOR, WORK_PER_FILE_BYTE),
            f"{who} ({tile_bytes:,} of the tiles' {all_bytes:,} bytes)",
            "its share of the file's, spec 10.15" + (" and 10.17" if span > 1 else ""),
        )


def allowance(size: int | RenderAllowance) -> RenderAllowance:
    """``size`` as an allowance: a file's size in bytes, or a tile's allowance as it is."""
    return size if isinstance(size, RenderAllowance) else RenderAllowance.of_file(size)


# The memory a decode takes (the whole process's peak resident memory: Python, torch and the restorer's
# network included; restoration and refinement on), for a file of F bytes whose views hold X pixels: at most
# DECODE_MEMORY_BASE + DECODE_MEMORY_PER_FILE_BYTE * F + DECODE_MEMORY_PER_PIXEL * X. Not a check: what the
# limits above add up to (Gaussians and pairs per byte, pixels per view), stated so that users can size a
# machine, and measured on real files and on files crafted at every limit (bench/robustness.md).
DECODE_MEMORY_BASE = 1 << 30
DECODE_MEMORY_PER_FILE_BYTE = 2048
DECODE_MEMORY_PER_PIXEL = 256


def decode_memory_bound(file_size: int, pixels: int) -> int:
    """The most memory (bytes) a decode of a ``file_size``-byte file with views of ``pixels`` takes."""
    return DECODE_MEMORY_BASE + DECODE_MEMORY_PER_FILE_BYTE * file_size + DECODE_MEMORY_PER_PIXEL * pixels


# --- input scenes (gspc/io/) -------------------------------------------------------------------------------

# Gaussians a compressed scene file (SPZ, SOG) of F bytes may declare: at most max(SCENE_GAUSSIAN_FLOOR,
# F // MIN_SCENE_BYTES_PER_GAUSSIAN), checked before anything of that size is inflated or allocated. Reading
# costs about 250 bytes per Gaussian (float64 arrays, then the float32 scene), so an SPZ of 0.95 MB declaring
# 50 million Gaussians (what its gzip expansion allowed) reached 6.5 GB before failing (issue 26). Real files
# hold 12 bytes or more per Gaussian (the SPZ fixtures 16-64, the statues' SOG 13); the floor, about 130 MB,
# admits any scene of up to 2^19 Gaussians however well it compresses.
SCENE_GAUSSIAN_FLOOR = 1 << 19
MIN_SCENE_BYTES_PER_GAUSSIAN = 4


def max_scene_gaussians(file_bytes: int) -> int:
    """The most Gaussians a compressed scene file of ``file_bytes`` bytes may declare."""
    return max(SCENE_GAUSSIAN_FLOOR, file_bytes // MIN_SCENE_BYTES_PER_GAUSSIAN)


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


# --- spatial tiles (format 1.5, spec 10.14) ----------------------------------------------------------------

# Tiles one file may hold: a tile has up to seven chunks and a file 65,535 (spec section 7), so 8,192 tiles
# of the encoder's default size hold far more Gaussians than any scene yet captured.
MAX_TILES = 1 << 13
# Tiles one tile's side information may draw with its own Gaussians (spec 10.15): a cube of neighbours
# (26) with room to spare; the Gaussians they add to its renders are bounded by its work budget.
MAX_DRAWN_TILES = 64
# Tiles one tile's side information may serve together (a span, spec 10.17): as many as it may draw, so a
# span's refinement holds at most what a tile drawing its neighbours may render.
MAX_SPAN_TILES = 64
# Gaussians the encoder puts in one tile by default (--tile-size): the chosen trade of bytes (each tile pays
# its own entropy models) against memory and parallel work (bench/tiles.md).
DEFAULT_TILE_SIZE = 1 << 18
# --tile-size at least this: smaller tiles pay their models more than their Gaussians.
MIN_TILE_SIZE = 1 << 10

# What decoding one tile of a tiled file may spend, P_k its attribute payload bytes and P all tiles': table
# entries at most max(FILE_TABLE_FLOOR x P_k // P, MODEL_ENTRIES_PER_BYTE x P_k), decompressed model lists at
# most max(FILE_MODEL_FLOOR x P_k // P, MODEL_LIST_RATIO x P_k). Each matrix keeps its own bounds (above);
# without these, every tile would bring its own floors, and a file of many tiny tiles could ask for
# thousands of them. The floors are what one untiled file may ask for at most (eight floors' worth of
# tables; 113 model lists at their floor: sixteen classes of seven chunks and the positions').
FILE_TABLE_FLOOR = 8 * MODEL_TABLE_FLOOR
FILE_MODEL_FLOOR = 1 << 23


class DecodeBudget:
    """The table entries and model-list bytes one tile of a tiled file may spend (spec 10.14): the file's
    floors shared among its tiles in proportion to their bytes, so each counts once per file, and each tile
    can be decoded alone (in parallel, or as part of a region) under the same rule. Each matrix spends
    once, when its models are read."""

    def __init__(self, tile_bytes: int, file_bytes: int) -> None:
        share = max(file_bytes, 1)
        self.table_entries = max(FILE_TABLE_FLOOR * tile_bytes // share, MODEL_ENTRIES_PER_BYTE * tile_bytes)
        self.model_bytes = max(FILE_MODEL_FLOOR * tile_bytes // share, MODEL_LIST_RATIO * tile_bytes)

    def spend_tables(self, entries: int) -> bool:
        """Spend ``entries`` table entries; False (nothing spent) where fewer are left."""
        if entries > self.table_entries:
            return False
        self.table_entries -= entries
        return True

    def spend_model_bytes(self, size: int) -> bool:
        """Spend ``size`` decompressed model-list bytes; False (nothing spent) where fewer are left."""
        if size > self.model_bytes:
            return False
        self.model_bytes -= size
        return True


# --- worker processes (gspc/workers.py) --------------------------------------------------------------------

# The memory one worker may need, for the default number of workers: no more are started than the available
# memory holds. A worker coding a tile of the default size holds its measure, search and tuning (the
# largest process of the tiled encodes in bench/tiles.md, with a margin); one decoding a tile, its chunks
# and Gaussians.
ENCODE_WORKER_BYTES = 2 << 30
DECODE_WORKER_BYTES = 512 << 20
# A span's task (spec 10.17) holds its tiles' original and coded Gaussians, their renders and one refinement
# of them all; decoding a span, the refinement of its Gaussians: per Gaussian of the span, with a margin over
# the largest processes of bench/tiles.md ("Side information shared by spans of tiles"; one block's decode in
# "Side information per tile").
SPAN_ENCODE_BYTES_PER_GAUSSIAN = 3 << 10
SPAN_DECODE_BYTES_PER_GAUSSIAN = 2 << 10


def encode_worker_bytes(span_size: int) -> int:
    """What one encode worker may need with tiles joined in spans of ``span_size`` Gaussians (0: none)."""
    return max(ENCODE_WORKER_BYTES, SPAN_ENCODE_BYTES_PER_GAUSSIAN * span_size)


def decode_worker_bytes(span_gaussians: int) -> int:
    """What one decode worker may need where the largest span it refines holds ``span_gaussians``."""
    return max(DECODE_WORKER_BYTES, SPAN_DECODE_BYTES_PER_GAUSSIAN * span_gaussians)
