"""The `gspc` command line: encode, decode, info, render, eval, convert.

Every user-caused failure ends as one line on stderr and exit status 1; set GSPC_DEBUG=1 for tracebacks.
Heavy modules (torch, the pipeline) are imported inside the commands that need them, so ``--help`` and
``info FILE.gspc`` start fast (bench/startup.md).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from gspc.atomic import check_output_path
from gspc.errors import GspcError
from gspc.options import DecodeOptions, EncodeOptions
from gspc.progress import ProgressLines
from gspc.workers import default_workers, error_line

app = typer.Typer(
    add_completion=False, no_args_is_help=True, help="gspc: a codec for 3D Gaussian Splatting scenes."
)
out = Console()
err = Console(stderr=True)
RENDER_DEVICE_HELP = "cpu or cuda (where the renders run)"
OUTPUT_HELP = "output scene, by its extension: .ply (INRIA layout), .spz (Niantic SPZ) or .glb (glTF)"


@contextmanager
def one_line_warnings(log=None):
    """Within: each warning (e.g. lens distortion ignored) is one ``gspc: warning: ...`` line on stderr,
    without Python's file name and source line (issue 26). ``log`` prints a line (default: stderr)."""
    log = log or _log_line

    def show(message, category, filename, lineno, file=None, line=None):
        log(f"warning: {message}")

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def _one_line_errors(fn):
    """Turn every failure into one line on stderr (tracebacks only with GSPC_DEBUG=1)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            with one_line_warnings():
                return fn(*args, **kwargs)
        except (GspcError, OSError, MemoryError) as e:
            msg = error_line(e)
        except typer.Exit:  # a command's own exit status (a batch where a scene failed, gspc view stopped)
            raise
        except KeyboardInterrupt:
            # The shell's convention for a run stopped by Ctrl-C (128 + SIGINT): scripts tell it from failure.
            err.print("[red]error:[/red] interrupted", highlight=False)
            raise typer.Exit(130) from None
        except Exception as e:  # an internal bug: still one line, with a way to see more
            if os.environ.get("GSPC_DEBUG"):
                raise
            msg = error_line(e)
        # Messages quote paths and install hints ("gspc[cuda]") that rich would read as markup and drop.
        err.print(f"[red]error:[/red] {escape(msg)}", highlight=False, soft_wrap=True)
        raise typer.Exit(1)

    return wrapper


# Threads inside one render or kernel when GSPC_THREADS is unset: one. Threads that wait for each other make a
# run on a busy machine slower than one thread (bench/threads.md); gspc's parallel work is its tiles, on
# worker processes (--workers), which do not wait for each other.
DEFAULT_THREADS = 1


def thread_count(value: str | None) -> int:
    """The torch threads GSPC_THREADS=``value`` asks for: unset or empty means DEFAULT_THREADS; a whole
    number from 1 up, clamped to the cores this process may use (more threads than cores only contend, and
    10000 once crashed libgomp); anything else is a GspcError naming the variable."""
    cores = default_workers()
    if value is None or not value.strip():
        return DEFAULT_THREADS
    text = value.strip()
    if not (text.isascii() and text.isdigit()) or not text.lstrip("0"):
        raise GspcError(f"GSPC_THREADS={value!r}: give a whole number of threads, 1 or more, or unset it")
    digits = text.lstrip("0")
    return min(int(digits) if len(digits) <= 18 else cores, cores)  # int() refuses over 4300 digits


def _use_threads() -> None:
    """Set torch's thread count (GSPC_THREADS, default one): called by the commands that compute."""
    import torch

    torch.set_num_threads(thread_count(os.environ.get("GSPC_THREADS")))


def _log_line(line: str) -> None:
    print(f"gspc: {line}", file=sys.stderr, flush=True)


@contextmanager
def _progress_bars():
    """A callback(stage, done, total): one rich bar per stage on a terminal, with each long stage's expected
    time announced above the bars; timed plain lines on stderr otherwise (logs, job queues, CI)."""
    if not err.is_terminal:
        yield ProgressLines(_log_line)
        return
    with Progress(
        TextColumn("{task.description:<16}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err,
        transient=False,
        disable=not err.is_terminal,
    ) as bars:
        tasks: dict[str, int] = {}
        announce = ProgressLines(
            lambda line: bars.console.print(line, highlight=False, markup=False), lines=False
        )

        def update(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bars.add_task(stage, total=total)
            bars.update(tasks[stage], completed=done, total=total)
            announce(stage, done, total)

        yield update


def _console_for(output: str) -> Console:
    """Where a command's report goes: stdout, unless its output is stdout itself (``-o /dev/stdout`` in a
    pipe), whose bytes the report would corrupt: then stderr."""
    try:
        same = os.path.samestat(os.stat(output), os.fstat(sys.stdout.fileno()))
    except Exception:  # no such path, or a stdout without a file descriptor (a test runner's)
        same = False
    return err if same else out


def _summary(title: str, rep, output: str) -> None:
    """The run's report: bytes per part (per Gaussian given and, where the encoder left some out, per
    Gaussian coded), seconds per stage, then what it decided, one fact a line."""
    console = _console_for(output)
    t = Table(title=title, show_header=True)
    given, coded = max(rep.num_gaussians_in, 1), max(rep.num_gaussians_out, 1)
    t.add_column("part")
    t.add_column("bytes", justify="right")
    t.add_column("B/Gaussian given" if given != coded else "B/Gaussian", justify="right")
    if given != coded:
        t.add_column("B/Gaussian coded", justify="right")
    for k, v in rep.bytes.items():
        t.add_row(k, f"{v:,}", f"{v / given:.2f}", *([f"{v / coded:.2f}"] if given != coded else []))
    console.print(t)
    s = Table(show_header=True)
    s.add_column("stage")
    s.add_column("seconds", justify="right")
    for k, v in rep.seconds.items():
        s.add_row(k, f"{v:.2f}")
    s.add_row("total", f"{sum(rep.seconds.values()):.2f}")
    console.print(s)
    for k, v in rep.info.items():
        console.print(f"{k}: {v}", markup=False, highlight=False, soft_wrap=True)


def _help(cls: type, name: str) -> str:
    """The help text of field ``name`` of an options dataclass (gspc/options.py)."""
    return next(f for f in dataclasses.fields(cls) if f.name == name).metadata["help"]


def _option(cls: type, name: str, *flags: str):
    """A typer option for field ``name`` of an options dataclass (gspc/options.py): the field's default and
    help, and its flag when it names one (else typer's ``--name``, ``--name/--no-name`` for switches)."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    flag = f.metadata.get("flag")
    if flag and isinstance(f.default, bool):
        flag = f"{flag}/--no-{flag[2:]}"
    return typer.Option(f.default, *flags, *([flag] if flag else []), help=f.metadata["help"])


@app.command()
@_one_line_errors
def encode(
    scenes: list[Path] = typer.Argument(
        ...,
        help="input scene: INRIA PLY, PlayCanvas SOG or compressed PLY, SPZ; several, or a folder of them "
        "(scene files, or folders holding point_cloud.ply and cameras.json): a batch, -o names a folder",
        metavar="SCENE...",
    ),
    output: str = typer.Option(..., "-o", "--output", help="output .gspc file (a batch: a folder)"),
    cameras: Path | None = typer.Option(None, help="cameras.json, transforms.json or COLMAP sparse folder"),
    quality: str = _option(EncodeOptions, "quality"),
    lam: float | None = _option(EncodeOptions, "lam"),
    target_size: int | None = _option(EncodeOptions, "target_size"),
    target_psnr: float | None = _option(EncodeOptions, "target_psnr"),
    views_fraction: float = _option(EncodeOptions, "views_fraction"),
    synth_views: int = _option(EncodeOptions, "synth_views"),
    max_side: int = _option(EncodeOptions, "max_side"),
    side_info: bool = _option(EncodeOptions, "side_info"),
    keep_invisible: bool = _option(EncodeOptions, "keep_invisible"),
    precision: bool = _option(EncodeOptions, "precision"),
    removal_search: bool = _option(EncodeOptions, "removal_search"),
    restorer: str = _option(EncodeOptions, "restorer"),
    check_iterations: int | None = _option(EncodeOptions, "check_iterations"),
    tune_iterations: int | None = _option(EncodeOptions, "tune_iterations"),
    background: tuple[float, float, float] = _option(EncodeOptions, "background"),
    device: str = _option(EncodeOptions, "device"),
    time_budget: float | None = _option(EncodeOptions, "time_budget"),
    tile_size: int = _option(EncodeOptions, "tile_size"),
    tile_neighbours: bool = _option(EncodeOptions, "tile_neighbours"),
    span_size: int = _option(EncodeOptions, "span_size"),
    workers: int | None = _option(EncodeOptions, "workers"),
    ray: str | None = _option(EncodeOptions, "ray"),
    ship_inputs: bool = _option(EncodeOptions, "ship_inputs"),
) -> None:
    """Compress a 3DGS scene into a .gspc file (several scenes: a batch, one file each)."""
    from gspc.batch import is_batch

    batch = is_batch(scenes)
    if not batch:
        check_output_path(output)  # the text as typed: a Path would drop a trailing slash
    elif cameras is not None:
        raise GspcError(
            "--cameras names one scene's cameras: in a batch, each scene folder's cameras.json is used"
        )
    from gspc.pipeline import encode as run

    _use_threads()

    opts = EncodeOptions(
        quality=quality,
        lam=lam,
        target_size=target_size,
        target_psnr=target_psnr,
        views_fraction=views_fraction,
        synth_views=synth_views,
        max_side=max_side,
        side_info=side_info,
        keep_invisible=keep_invisible,
        precision=precision,
        removal_search=removal_search,
        background=background,
        check_iterations=check_iterations,
        tune_iterations=tune_iterations,
        restorer=restorer,
        device=device,
        time_budget=time_budget,
        tile_size=tile_size,
        tile_neighbours=tile_neighbours,
        span_size=span_size,
        workers=workers,
        ray=ray,
        ship_inputs=ship_inputs,
    )
    if batch:
        _encode_batch(scenes, output, opts)
        return
    with _progress_bars() as cb:
        rep = run(scenes[0], output, cameras, opts, progress=cb)
    _summary(f"gspc encode -> {output}", rep, output)


def _encode_batch(paths: list[Path], output: str, opts: EncodeOptions) -> None:
    """``gspc encode`` of several scenes: a line for each as it ends (a failure as an error line of its
    own), then a table of them all; exit status 1 where any failed."""
    from gspc.batch import encode_batch, find_scenes

    scenes = find_scenes(paths)

    def done(r) -> None:
        if r.error is None:
            _log_line(f"{r.name}: {r.bytes:,} B in {r.seconds:.1f} s -> {r.output}")
        else:
            err.print(f"[red]error:[/red] {escape(f'{r.name}: {r.error}')}", highlight=False, soft_wrap=True)

    with _progress_bars() as cb:
        results = encode_batch(scenes, output, opts, progress=cb, done=done)
    t = Table(title=f"gspc encode -> {output} ({len(results)} scenes)", show_header=True)
    for col in ("scene", "Gaussians", "bytes", "B/Gaussian", "seconds", "result"):
        t.add_column(col, justify="left" if col in ("scene", "result") else "right")
    for r in results:
        if r.error is None:
            per = r.bytes / max(r.given, 1)
            cells = (f"{r.given:,}", f"{r.bytes:,}", f"{per:.2f}", f"{r.seconds:.1f}", "ok")
        else:
            cells = ("", "", "", "", "error")
        t.add_row(escape(r.name), *cells)
    out.print(t)
    if any(r.error is not None for r in results):
        raise typer.Exit(1)


@app.command()
@_one_line_errors
def decode(
    source: Path = typer.Argument(..., help="input .gspc file"),
    output: str = typer.Option(..., "-o", "--output", help=OUTPUT_HELP),
    iterations: int | None = _option(DecodeOptions, "iterations"),
    restore: bool = _option(DecodeOptions, "restore"),
    refine: bool = _option(DecodeOptions, "refine"),
    restorer: str | None = _option(DecodeOptions, "restorer"),
    in_cells: bool = _option(DecodeOptions, "in_cells"),
    device: str = _option(DecodeOptions, "device"),
    time_budget: float | None = _option(DecodeOptions, "time_budget"),
    region: str | None = typer.Option(
        None, help=_help(DecodeOptions, "region"), metavar="XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX"
    ),
    workers: int | None = _option(DecodeOptions, "workers"),
    ray: str | None = _option(DecodeOptions, "ray"),
) -> None:
    """Decode a .gspc file into a 3DGS scene: PLY, SPZ or glb, as the output's extension names."""
    check_output_path(output)
    from gspc.pipeline import decode as run

    _use_threads()

    opts = DecodeOptions(
        iterations=iterations,
        restore=restore,
        refine=refine,
        restorer=restorer,
        device=device,
        in_cells=in_cells,
        time_budget=time_budget,
        region=region,
        workers=workers,
        ray=ray,
    )
    with _progress_bars() as cb:
        rep = run(source, output, opts, progress=cb)
    _summary(f"gspc decode -> {output}", rep, output)


def _is_gspc(path: Path) -> bool:
    from gspc.format.container import MAGIC

    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def _position_grid_line(grid) -> str:
    """How a .gspc file codes its positions (spec 10.1), for ``gspc info``."""
    if not grid.is_contracted:
        return f"positions: a box grid of {grid.bits} bits per axis"
    line = f"positions: a contracted grid of {grid.bits} bits per axis"
    if grid.far is not None:
        line += f"; a far set of {grid.far.count:,} Gaussians on a grid {grid.far.shift} bits coarser"
    return line


def _precision_line(section) -> str:
    """A version-4 or -5 file's precision classes (spec 10.13) and SH codebook (10.16), from the header
    alone, for ``gspc info``."""
    steps = [c.scale_step for c in section.all_classes]
    book = f", the SH rest by a codebook of {section.codebook:,} entries" if section.codebook else ""
    return (
        f"precision: {len(steps)} classes per Gaussian (log-scale steps {min(steps):.3g} to "
        f"{max(steps):.3g}), an SH degree per Gaussian{book} (attribute codec version {section.version})"
    )


@app.command()
@_one_line_errors
def info(
    path: Path = typer.Argument(..., help="a scene (PLY/SOG/compressed PLY/SPZ) or a .gspc file"),
) -> None:
    """Print what a file holds: counts, bounds, statistics, or a .gspc file's byte budget."""
    if not path.exists():
        raise GspcError(f"{path}: no such file")
    if _is_gspc(path):
        from gspc.format.container import read_bytes
        from gspc.format.file import FileReader, read_file

        with FileReader(path) as reader:  # a tiled file's head and index: its tiles are not read
            if reader.tiles is not None:
                _tiled_info(path, reader)
                return
        f = read_file(read_bytes(path))  # parsed and checked once, as a decode reads it
        summary, fields = f.header.scene, f.header
        n = max(fields.attributes.n, 1)
        degree = fields.attributes.sh_degree
        source = (
            f", {summary.source_gaussians:,} given to the encoder"
            if summary and summary.source_gaussians
            else ""
        )
        out.print(
            f"{path}: gspc format {f.version[0]}.{f.version[1]}, {f.file_size:,} bytes, "
            f"{fields.attributes.n:,} Gaussians{source}, SH degree {degree}, "
            f"{len(f.side.views)} side-information views ({len(f.side.images)} with a residual)",
            markup=False,
        )
        if summary is not None and summary.coordinates is not None:
            out.print(f"coordinates: {summary.coordinates} (as the source stated them)")
        _fidelity_line(summary)
        out.print(_position_grid_line(fields.attributes.position))
        if fields.attributes.precision:
            out.print(_precision_line(fields.attributes))
        _budget_table(f.budget, f.chunks, n)
        return
    from gspc.io import read_scene
    from gspc.stats import scene_stats

    _use_threads()

    st = scene_stats(read_scene(path))
    t = Table(title=escape(str(path)), show_header=True)
    t.add_column("statistic")
    t.add_column("value", justify="right")
    for k, v in _flatten(st):
        t.add_row(k, _fmt(v))
    out.print(t)


def _fidelity_line(summary, which: str = "") -> None:
    """The fidelity the encoder coded to, where the header states one (spec 10.8 ``scene.psnr_db``)."""
    if summary is not None and summary.psnr_db is not None:
        out.print(
            f"fidelity: {summary.psnr_db:.2f} dB{which}, the decoded attributes against the original's "
            "renders at views between the encoder's cameras"
        )


def _budget_table(budget: dict[str, int], chunks, n: int) -> None:
    """A .gspc file's bytes per part (chunks or chunk-table entries: anything with a ``type``)."""
    t = Table(show_header=True)
    for col in ("part", "chunks", "bytes", "B/Gaussian", "share"):
        t.add_column(col, justify="left" if col == "part" else "right")
    size = budget["file"]
    for part, b in budget.items():
        if part == "file":
            continue
        cnt = sum(1 for c in chunks if c.type == part)
        t.add_row(part, str(cnt) if cnt else "", f"{b:,}", f"{b / n:.2f}", f"{b / size:.1%}")
    out.print(t)


# Tiles ``gspc info`` lists one by one; a file of more is summed up after them.
INFO_TILES = 32


def _tiled_info(path: Path, reader) -> None:
    """``gspc info`` of a tiled file, from its head and tile index alone (spec 10.14)."""
    from gspc.format.chunks import TSID

    tiles, head = reader.tiles, reader.head
    summary = reader.header.scene
    n = tiles.num_gaussians
    source = (
        f", {summary.source_gaussians:,} given to the encoder" if summary and summary.source_gaussians else ""
    )
    sides = {e.index: e.length for e in head.entries if e.type == TSID}  # each tile's own (spec 10.15)
    views = "side information per tile" if sides else f"{len(reader.side.views)} side-information views"
    out.print(
        f"{path}: gspc format {head.version[0]}.{head.version[1]}, {head.file_size:,} bytes, {n:,} Gaussians"
        f"{source} in {len(tiles.tiles)} tiles, SH degree {tiles.sh_degree}, {views}",
        markup=False,
    )
    if summary is not None and summary.coordinates is not None:
        out.print(f"coordinates: {summary.coordinates} (as the source stated them)")
    _fidelity_line(summary, " (its lowest tile's)")
    _budget_table(reader.budget, head.entries, max(n, 1))
    sizes = reader.tile_bytes()
    if sides:
        own = f"{len(sides)} of {len(tiles.tiles)} tiles, {sum(sides.values()):,} B"
        drawn = ", each drawn with the tiles it names" if any(t.drawn for t in tiles.tiles) else ""
        spans = [t.span for t in tiles.tiles if t.span > 1]
        if spans:  # spec 10.17
            drawn += f"; {len(spans)} serve spans of {min(spans)}-{max(spans)} tiles, refined as one"
        out.print(f"side information of their own (refined tile by tile{drawn}): {own}")
    t = Table(show_header=True)
    box_col = "box (x, y, z from .. to)"
    columns = (
        "tile",
        "Gaussians",
        "bytes",
        "B/Gaussian",
        box_col,
        "grid",
        "classes",
        "side B",
        "drawn",
        "span",
    )
    for col in columns:
        t.add_column(col, justify="left" if col.startswith("box") else "right")
    for k, tile in enumerate(tiles.tiles[:INFO_TILES]):
        b = tile.box
        box = ", ".join(f"{b[a]:.3g}..{b[a + 3]:.3g}" for a in range(3))
        grid = f"{tile.section.position.bits} bits" + (", far set" if tile.section.position.far else "")
        t.add_row(
            str(k), f"{tile.n:,}", f"{sizes[k]:,}", f"{sizes[k] / tile.n:.2f}", box, grid,
            str(len(tile.section.all_classes)), f"{sides[k]:,}" if k in sides else "-",
            " ".join(map(str, tile.drawn)) or "-", f"{k}-{k + tile.span - 1}" if tile.span > 1 else "-",
        )  # fmt: skip
    out.print(t)
    if len(tiles.tiles) > INFO_TILES:
        rest = tiles.tiles[INFO_TILES:]
        out.print(f"... and {len(rest)} more tiles of {sum(t.n for t in rest):,} Gaussians")


def _flatten(d, prefix=""):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _flatten(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return f"{v:,}" if isinstance(v, int) else str(v)


def _check_view_options(views: int, max_side: int) -> None:
    from gspc.options import check_max_side, check_synth_views

    check_synth_views(views)
    check_max_side(max_side)


def _cameras_for(scene, cameras: Path | None, views: int, max_side: int):
    from gspc.io.camera_files import load_cameras
    from gspc.views import limit_size, synthesize_views

    cams = load_cameras(cameras) if cameras else synthesize_views(scene, views)
    return limit_size(cams, max_side)


@app.command()
@_one_line_errors
def render(
    scene: Path = typer.Argument(..., help="scene file (PLY/SOG/compressed PLY/SPZ)"),
    output: Path = typer.Option(..., "-o", "--output", help="folder for the PNGs"),
    cameras: Path | None = typer.Option(None, help="camera file; default: synthesised views"),
    views: int = typer.Option(8, help="views to synthesise when no cameras are given"),
    max_side: int = typer.Option(800, help="longest image side in pixels"),
    device: str = typer.Option("cpu", help=RENDER_DEVICE_HELP),
) -> None:
    """Render a scene to PNGs."""
    from gspc.paths import refuse_output_over_input

    _check_view_options(views, max_side)
    refuse_output_over_input(output, scene, cameras)
    _use_threads()
    import imagecodecs

    from gspc.device import check_device
    from gspc.io import read_scene
    from gspc.reconstruct import render_images

    dev = check_device(device)
    sc = read_scene(scene).to(dev)
    cams = _cameras_for(sc, cameras, views, max_side)
    output.mkdir(parents=True, exist_ok=True)
    with _progress_bars() as cb:
        imgs = render_images(sc, cams, (0.0, 0.0, 0.0), cb)
    for i, (cam, img) in enumerate(zip(cams, imgs)):
        name = (cam.name or f"view_{i:03d}").replace("/", "_")
        tmp = output / f".{name}.png.tmp"
        tmp.write_bytes(imagecodecs.png_encode((img.cpu().numpy() * 255 + 0.5).astype("uint8")))
        os.replace(tmp, output / f"{name}.png")
    out.print(f"wrote {len(imgs)} images to {output}", markup=False)


@app.command(name="eval")
@_one_line_errors
def evaluate(
    reference: Path = typer.Argument(..., help="reference scene (PLY/SOG/compressed PLY/SPZ)"),
    test: Path = typer.Argument(..., help="scene to score against the reference's renders"),
    cameras: Path | None = typer.Option(None, help="camera file; default: synthesised views"),
    views: int = typer.Option(16, help="views to synthesise when no cameras are given"),
    max_side: int = typer.Option(400, help="longest image side in pixels"),
    background: tuple[float, float, float] = typer.Option(
        (0.0, 0.0, 0.0), help="render background RGB in [0, 1] (use the one the scene was encoded with)"
    ),
    device: str = typer.Option("cpu", help=RENDER_DEVICE_HELP),
) -> None:
    """PSNR and SSIM of one scene's renders against another's (8-bit, 3DGS convention)."""
    from gspc.options import check_background

    _check_view_options(views, max_side)
    background = check_background(background)
    _use_threads()
    from gspc.device import check_device
    from gspc.io import read_scene
    from gspc.metrics import mean_psnr, quantize8, ssim
    from gspc.reconstruct import render_images

    dev = check_device(device)
    ref, tst = read_scene(reference).to(dev), read_scene(test).to(dev)
    cams = _cameras_for(ref, cameras, views, max_side)
    with _progress_bars() as cb:
        a = render_images(ref, cams, background, cb, "render reference")
        b = render_images(tst, cams, background, cb, "render test")
    p = mean_psnr(a, b)
    s = sum(float(ssim(quantize8(x), quantize8(y))) for x, y in zip(a, b)) / len(cams)
    out.print(f"views: {len(cams)}  PSNR: {p:.3f} dB  SSIM: {s:.4f}")


@app.command()
@_one_line_errors
def convert(
    scene: Path = typer.Argument(..., help="scene file (PLY/SOG/compressed PLY/SPZ)"),
    output: str = typer.Option(..., "-o", "--output", help=OUTPUT_HELP),
) -> None:
    """Convert any readable scene to PLY, SPZ or glb, as the output's extension names."""
    from gspc.paths import refuse_output_over_input

    check_output_path(output)
    refuse_output_over_input(output, scene)
    _use_threads()
    from gspc.io import read_scene, scene_writer

    write = scene_writer(output)
    sc = read_scene(scene)
    write(sc, output)
    _console_for(output).print(
        f"wrote {sc.num_gaussians:,} Gaussians (SH degree {sc.sh_degree}) to {output}", markup=False
    )


@app.command()
@_one_line_errors
def view(
    scene: Path = typer.Argument(..., help="the .gspc file to show"),
    port: int = typer.Option(0, help="port on 127.0.0.1 to serve on (0: a free one)"),
) -> None:
    """Serve a .gspc file and the web viewer (web/viewer) on 127.0.0.1, and print the address to open."""
    from gspc.view import serve

    try:
        serve(scene, port, lambda line: out.print(line, markup=False, highlight=False, soft_wrap=True))
    except KeyboardInterrupt:
        # Ctrl-C is how a server stops: no error, and the shell's status for it (128 + SIGINT).
        out.print("gspc view: stopped", markup=False, highlight=False)
        raise typer.Exit(130) from None


def main() -> None:  # pragma: no cover - console script entry
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
