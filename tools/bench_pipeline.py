"""End-to-end benchmark of gspc: attribute codec, side information, restoration and refinement.

    python tools/bench_pipeline.py --lego /work/fits/lego200_20k [--donut] [--statues massa] \
        [--iterations 300] [--sweep 0,100,300,1000,3000] [--lams 3,6,12,24] \
        [--before] [--gain-lams 3,5,7,9,13] [--no-side-rows]

Per scene (lego fits: against the held-out photos and the original's renders; donut and statues:
against the original's renders), all at views the side information did NOT cover:
- rows: original; G~ only; G~ refined on I~ + R~; G~ refined on the restorer's output (if shipped);
- a rate-distortion comparison at equal total bytes: the attribute codec alone over a lambda sweep
  versus gspc (codec + side information + refinement) at the same lambdas;
- decode iterations against PSNR and seconds;
- with --before, every preset also coded by the uniform attribute codec (precision off) at its lambda of
  before, in the same run; with --gain-lams, each row's gain over the codec alone at equal bytes.
Writes bench/pipeline.md and bench/pipeline_rd.png.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import typer
from bench_setups import SHARED, Setup, fit_setup, run_point, score, synth_setup

from gspc.io import read_scene
from gspc.reconstruct import render_images
from gspc.restore.restorer import available_restorers

# The presets' attribute lambdas before per-Gaussian precision (attribute codec version 4) came in.
BEFORE_LAMS = {"low": 8.0, "high": 1.0}


def fmt_row(label: str, r: dict, n_in: int, photos: bool) -> str:
    cells = [label]
    if photos:
        cells += [f"{r.get('psnr_photo', float('nan')):.2f}", f"{r.get('ssim_photo', float('nan')):.4f}"]
    p = r["psnr"]
    cells += [
        "∞" if p == float("inf") else f"{p:.2f}",
        f"{r['ssim']:.4f}",
        f"{r['bytes']:,}",
        f"{r['side']:,}" + (f" (1/{r['scale']})" if r.get("scale") else ""),
        f"{r['bytes'] / n_in:.2f}",
        f"{r.get('encode_s', 0):.1f}",
        f"{r.get('decode_s', 0):.1f}",
    ]
    return "| " + " | ".join(cells) + " |"


def bench_scene(
    s: Setup,
    tmp: Path,
    iterations: int,
    sweep: list[int],
    lams: list[float],
    restorers: list[str],
    lines: list[str],
    curves: dict,
    gain_lams: list[float] | None = None,
    before: bool = False,
    side_rows: bool = True,
) -> None:
    scene = read_scene(s.scene_path)
    n_in = scene.num_gaussians
    its_text = "the file's iterations" if iterations is None else f"{iterations} iterations"
    ref = render_images(scene, s.eval_cams, s.background)
    photos = s.photos is not None
    print(
        f"== {s.name}: {n_in} Gaussians, {len(s.train_cams)} train / {len(s.eval_cams)} eval views",
        flush=True,
    )
    lines += [
        f"### {s.name}",
        "",
        f"{n_in:,} Gaussians (SH degree {scene.sh_degree}); side information at 40% of "
        f"{len(s.train_cams)} views; scored at {len(s.eval_cams)} other views "
        f"({s.eval_cams[0].width}x{s.eval_cams[0].height}).",
        "",
    ]
    head = (
        ["row"]
        + (["PSNR photos", "SSIM photos"] if photos else [])
        + [
            "PSNR vs original",
            "SSIM vs original",
            "bytes",
            "side info B",
            "B/Gaussian",
            "encode s",
            "decode s",
        ]
    )
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    orig = score(s.scene_path, s, ref)
    orig.update(bytes=s.scene_path.stat().st_size, side=0)
    lines.append(
        fmt_row("original (PLY)" if s.scene_path.suffix == ".ply" else "original", orig, n_in, photos)
    )
    rows: list[tuple[str, dict]] = []  # (label, result) of every coded row, for the equal-bytes gains

    def add(label: str, r: dict) -> None:
        rows.append((label, r))
        lines.append(fmt_row(label, r, n_in, photos))
        print(lines[-1], flush=True)

    for q in ("low", "high"):
        # Before and after in one run, interleaved: "before" is the uniform attribute codec (precision off)
        # at the lambda the preset had before per-Gaussian precision (gspc/presets.py).
        for code, kw in ([("before", dict(precision=False, lam=BEFORE_LAMS[q]))] if before else []) + [
            ("after" if before else "", {})
        ]:
            p = f"{q} {code}".strip()
            r = run_point(s, tmp, ref, quality=q, refine=False, restore=False, tag=f"{p}_plain", **kw)
            add(f"{p}: G~ only", r)
            if side_rows:
                r = run_point(s, tmp, ref, quality=q, iterations=iterations, tag=f"{p}_none", **kw)
                add(f"{p}: G~ refined on I~ + R~ (refine: {r['refine']})", r)
                if q == "low" and r["side"]:  # the quantisation cells' share of the gain
                    r = run_point(
                        s, tmp, ref, quality=q, iterations=iterations, cells=False, tag=f"{p}_free", **kw
                    )
                    add(f"{p}: G~ refined on I~ + R~ (refine: {r['refine']})", r)
            for name in restorers:
                r = run_point(
                    s, tmp, ref, quality=q, iterations=iterations, restorer=name, tag=f"{p}_{name}", **kw
                )
                add(f"{p}: G~ refined on restorer '{name}' (refine: {r['refine']})", r)
    lines.append("")
    if gain_lams:
        curves[s.name] = _equal_bytes_gains(s, tmp, ref, gain_lams, rows, lines, before)

    if lams:
        lines += [
            "Rate-distortion at equal total bytes (PSNR vs the original's renders): the attribute codec "
            "alone at each lambda, and gspc at the same lambda with the low preset's side information "
            f"(the encoder's check decides whether it is sent; decode: {its_text}). Gain = PSNR minus the "
            "codec-alone curve interpolated (in log bytes) at the same total bytes.",
            "",
            "Columns 'side info always' show the side-information path with the check off (the preset's "
            "residuals at 1/2 resolution); where the check kept side information they repeat gspc's. "
            "1/k: the resolution of the residuals gspc sent. The codec-alone curve is also sampled halfway "
            "(geometric mean) between consecutive lambdas, for the interpolation and the plot.",
            "",
            "| lambda | codec bytes | codec PSNR | side info always: bytes (side info) | PSNR | gain "
            "| gspc bytes (side info) | gspc PSNR | gain, equal bytes | gspc encode s | gspc decode s |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        base, full, forced = [], [], []
        for lam in lams:
            b = run_point(s, tmp, ref, lam=lam, side_info=False, refine=False, restore=False, tag=f"b{lam}")
            f = run_point(s, tmp, ref, lam=lam, iterations=iterations, tag=f"f{lam}")
            a = (
                f
                if f["side"]
                else run_point(s, tmp, ref, lam=lam, iterations=iterations, check=False, tag="a")
            )
            base.append((b["bytes"], b["psnr"]))
            full.append((f["bytes"], f["psnr"], f["side"], f["encode_s"], f["decode_s"], f["scale"]))
            forced.append((a["bytes"], a["psnr"], a["side"]))
            print(
                f"lambda {lam}: codec {b['bytes']} {b['psnr']:.2f}, gspc {f['bytes']} {f['psnr']:.2f}, "
                f"forced {a['bytes']} {a['psnr']:.2f}",
                flush=True,
            )
        mids = [float(np.sqrt(a * b)) for a, b in zip(lams[:-1], lams[1:])]
        curve = list(base)
        for lam in mids:
            m = run_point(s, tmp, ref, lam=lam, side_info=False, refine=False, restore=False, tag=f"m{lam}")
            curve.append((m["bytes"], m["psnr"]))
        bx = np.log([p[0] for p in curve])
        by = np.array([p[1] for p in curve])
        order = np.argsort(bx)
        lo, hi = bx[order][0], bx[order][-1]

        def gain(nbytes: int, p: float) -> str:
            x = np.log(nbytes)
            if not lo <= x <= hi:
                return "outside the codec's range"
            return f"{p - float(np.interp(x, bx[order], by[order])):+.2f} dB"

        for lam, (bb, bp), (fb, fp, side, es, ds, sc), (ab, ap, aside) in zip(lams, base, full, forced):
            sent = f"{side:,}, 1/{sc}" if side else "0"
            lines.append(
                f"| {lam} | {bb:,} | {bp:.2f} | {ab:,} ({aside:,}) | {ap:.2f} | {gain(ab, ap)} "
                f"| {fb:,} ({sent}) | {fp:.2f} | {gain(fb, fp)} | {es:.0f} | {ds:.0f} |"
            )
        lines.append("")
        curves[s.name] = {
            "codec alone": sorted(curve),
            "side info always": [(b, p) for b, p, _ in forced],
            "gspc": [(b, p) for b, p, *_ in full],
        }

    if sweep:
        lines += [
            "Decode iterations (low preset, restorer 'none') against quality and time, CPU, one thread:",
            "",
            "| iterations | PSNR vs original | " + ("PSNR photos | " if photos else "") + "decode s |",
            "|---|---|" + ("---|" if photos else "") + "---|",
        ]
        for it in sweep:
            r = run_point(s, tmp, ref, iterations=it, tag=f"sweep{it}")
            ph = f"{r['psnr_photo']:.2f} | " if photos else ""
            lines.append(f"| {it} | {r['psnr']:.2f} | {ph}{r['decode_s']:.1f} |")
            print(lines[-1], flush=True)
        lines.append("")


def _codec_curve(s: Setup, tmp: Path, ref, lams: list[float], precision: bool) -> list[tuple]:
    """The attribute codec alone (low preset, no side information, no refinement): (bytes, PSNR, photos)."""
    curve = []
    for lam in lams:
        b = run_point(
            s, tmp, ref, lam=lam, side_info=False, refine=False, restore=False, precision=precision, tag="c"
        )
        curve.append((b["bytes"], b["psnr"], b.get("psnr_photo")))
    return sorted(curve)


def _equal_bytes_gains(
    s: Setup,
    tmp: Path,
    ref,
    lams: list[float],
    rows: list[tuple[str, dict]],
    lines: list[str],
    before: bool = False,
) -> dict:
    """Each row's PSNR against the codec-alone curve (attributes only, at ``lams``) at the row's bytes; with
    ``before`` also against the uniform codec's curve (precision off), the codec alone of before. Returns the
    curves and the rows as points, for the plot."""
    curves = {"codec alone": _codec_curve(s, tmp, ref, lams, True)}
    if before:
        curves = {
            "codec alone (v4, precision)": curves["codec alone"],
            "uniform codec alone": _codec_curve(s, tmp, ref, lams, False),
        }
    lines += [
        "Equal-bytes gain of each row over the attribute codec alone (low preset's parameters, no side "
        f"information, no refinement) at lambda {', '.join(f'{x:g}' for x in lams)}, interpolated in log "
        "bytes:",
        "",
        "| codec | lambda | bytes | PSNR vs original |" + (" PSNR photos |" if s.photos else ""),
        "|---|---|---|---|" + ("---|" if s.photos else ""),
    ]
    for name, curve in curves.items():
        for lam, (nb, p, pp) in zip(sorted(lams, reverse=True), curve):
            lines.append(f"| {name} | {lam:g} | {nb:,} | {p:.2f} |" + (f" {pp:.2f} |" if s.photos else ""))
    head = ["row", "bytes"]
    for name in curves:
        head += [f"gain over {name}, vs original's renders"] + (
            [f"over {name}, vs photos"] if s.photos else []
        )
    lines += ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, r in rows:
        x = float(np.log(r["bytes"]))
        cells = [label, f"{r['bytes']:,}"]
        for curve in curves.values():
            bx = np.log([c[0] for c in curve])
            keys = [("psnr", 1)] + ([("psnr_photo", 2)] if s.photos else [])
            for key, k in keys:
                inside = bx[0] <= x <= bx[-1]
                g = r[key] - float(np.interp(x, bx, [c[k] for c in curve])) if inside else None
                cells.append("outside the curve" if g is None else f"{g:+.2f} dB")
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    print("\n".join(lines[-len(rows) - 2 :]), flush=True)
    points = {name: [(c[0], c[1]) for c in curve] for name, curve in curves.items()}
    for label, r in rows:  # the full decodes (restorer rows), one point each
        if "restorer" in label:
            points.setdefault(label.split(":")[0] + ", full decode", []).append((r["bytes"], r["psnr"]))
    return points


def plot(curves: dict, path: Path) -> None:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(curves), figsize=(5 * len(curves), 4), squeeze=False)
    for ax, (name, cs) in zip(axes[0], curves.items()):
        for label, pts in cs.items():
            pts = sorted(pts)
            ax.plot([b / 1024 for b, _ in pts], [p for _, p in pts], "o-", label=label)
        ax.set_xscale("log")
        kib = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:.0f}")
        ax.xaxis.set_minor_locator(matplotlib.ticker.LogLocator(subs=(1.0, 1.5, 2.0, 3.0, 5.0, 7.0)))
        ax.xaxis.set_major_formatter(kib)
        ax.xaxis.set_minor_formatter(kib)
        ax.set_xlabel("total KiB")
        ax.set_ylabel("PSNR vs original renders (dB)")
        ax.set_title(name)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(
    lego: list[Path] = typer.Option(
        [], help="fit folders (tools/fit_scene.py output: lego fits or real captures such as the bird)"
    ),
    donut: bool = typer.Option(True, help="include ../shared/data/donut/fused.ply"),
    statues: list[str] = typer.Option(["massa"], help="statue names from ../shared/data/statues"),
    iterations: int | None = typer.Option(None, help="decode iterations (default: the file's)"),
    sweep: str = typer.Option(
        "0,100,300,1000,3000", help="decode iterations for the speed table ('' to skip)"
    ),
    sweep_scenes: int = typer.Option(1, help="how many scenes (in order) get the iteration sweep"),
    lams: str = typer.Option("3,6,12,24", help="lambdas of the rate-distortion comparison ('' to skip)"),
    gain_lams: str = typer.Option(
        "", help="lambdas of a codec-alone curve for every row's equal-bytes gain ('' to skip)"
    ),
    rd_scenes: int = typer.Option(2, help="how many scenes (in order) get the rate-distortion comparison"),
    restorers: str = typer.Option("", help="restorers of the rows table, comma-separated (default: all)"),
    out: Path = typer.Option(Path("bench/pipeline.md")),
    append: bool = typer.Option(
        False, help="add these scenes to an existing OUT (scenes benched in two runs)"
    ),
    before: bool = typer.Option(
        False,
        help="also the uniform attribute codec (--no-precision) at the presets' lambdas of before, "
        "side by side in this run",
    ),
    side_rows: bool = typer.Option(
        True, help="rows refined on I~ + R~ (and with the cells off); off: G~ only and the restorers' rows"
    ),
) -> None:
    torch.set_num_threads(1)
    setups = [fit_setup(p) for p in lego]
    if donut:
        setups.append(synth_setup("donut", SHARED / "donut" / "fused.ply"))
    setups += [
        synth_setup(f"statue {n} (SOG, already quantised)", SHARED / "statues" / f"{n}.sog")
        for n in statues
        if n
    ]
    restorers_l = [r for r in restorers.split(",") if r] or [r for r in available_restorers() if r != "none"]
    sweep_l = [int(x) for x in sweep.split(",") if x]
    lams_l = [float(x) for x in lams.split(",") if x]
    lines = [
        "# gspc end to end",
        "",
        f"Command: `python {' '.join(sys.argv)}`",
        "",
        "CPU, one thread (2-core machine, timings noisy). PSNR/SSIM on 8-bit renders (3DGS convention). "
        "Bytes are whole .gspc files (attributes + side information + header); 'original' is the input file.",
        "",
    ]
    png = f"{out.stem}_rd.png"
    if append and out.is_file():
        lines = out.read_text().rstrip("\n").split("\n") + [
            "",
            f"Appended by: `python {' '.join(sys.argv)}`",
            "",
        ]
        png = f"{out.stem}_rd_more.png"
    curves: dict = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        for k, s in enumerate(setups):
            bench_scene(
                s,
                Path(d),
                iterations,
                sweep_l if k < sweep_scenes else [],
                lams_l if k < rd_scenes else [],
                restorers_l,
                lines,
                curves,
                [float(x) for x in gain_lams.split(",") if x],
                before,
                side_rows,
            )
            out.write_text("\n".join(lines) + "\n")
    lines.append(f"Benchmark time (this run): {time.perf_counter() - t0:.0f} s.")
    if curves:
        plot(curves, out.with_name(png))
        lines += ["", f"![rate-distortion]({png})"]
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    typer.run(main)
