"""The far set (attribute codec version 3, gspc/codec/positions.py) on a real capture: bytes and quality of
the codec alone with and without it, over a lambda sweep.

    python tools/bench_far_set.py /work/fits/bird_q4_100k -o bench/far_set.md

The scene is a tools/fit_scene.py output (point_cloud.ply, cameras.json, test/*.png held-out photos,
fit.json), as tools/bench_peers.py reads it. Each lambda is encoded twice by `gspc encode --no-side-info`
with the training cameras: as this checkout writes it, and with the far set turned off (the contracted grid
alone, version 2); each file is decoded without refinement and rendered at the held-out views. PSNR: 8-bit
renders against the original scene's renders, over the whole frame, and against the photos.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

import torch
import typer
from bench_setups import fit_setup, held_out_line

from gspc.codec import positions
from gspc.format import container
from gspc.format.attribute_section import AttributeSection
from gspc.io import read_scene
from gspc.io.cameras_json import save_cameras_json
from gspc.metrics import mean_psnr
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode, render_images


def main(
    fit: Path = typer.Argument(..., help="tools/fit_scene.py output folder"),
    lams: str = typer.Option("1,2,4,8,16,32", help="lambdas"),
    out: Path = typer.Option(Path("bench/far_set.md"), "-o"),
) -> None:
    torch.set_num_threads(1)
    setup = fit_setup(fit)
    ply, bg, eval_cams, photos = setup.scene_path, setup.background, setup.eval_cams, setup.photos
    scene = read_scene(ply)
    ref = render_images(scene, eval_cams, bg)
    tmp = Path(tempfile.mkdtemp())
    cams_file = tmp / "train.json"
    save_cameras_json(setup.train_cams, cams_file)
    max_side = max(max(c.width, c.height) for c in [*setup.train_cams, *eval_cams])

    def run(lam: float, far: bool) -> dict:
        g, o = tmp / f"l{lam}_{far}.gspc", tmp / f"l{lam}_{far}.ply"
        opts = EncodeOptions(lam=lam, side_info=False, max_side=max_side, background=bg)
        t0 = time.perf_counter()
        if far:
            encode(ply, g, cams_file, opts)
        else:
            with mock.patch.object(positions, "far_set", lambda *a: (0, None)):
                encode(ply, g, cams_file, opts)
        seconds = time.perf_counter() - t0
        attrs = AttributeSection.from_dict(container.read(g).header["attributes"])
        posn = next(len(c.payload) for c in container.read(g).chunks if c.type == "POSN")
        decode(g, o, DecodeOptions(refine=False, restore=False))
        imgs = render_images(read_scene(o), eval_cams, bg)
        far = attrs.position.far
        return {
            "bytes": g.stat().st_size,
            "posn": posn,
            "n": attrs.n,
            "version": attrs.version,
            "far": f"{far.count:,} at {far.shift} bits" if far is not None else "-",
            "psnr": mean_psnr(imgs, ref),
            "photos": mean_psnr(imgs, photos),
            "seconds": seconds,
        }

    rows = []
    for lam in [float(x) for x in lams.split(",")]:
        off, on = run(lam, False), run(lam, True)
        rows.append(
            f"| {lam:g} | {off['bytes']:,} | {on['bytes']:,} | {on['bytes'] / off['bytes']:.3f} | "
            f"{off['posn']:,} | {on['posn']:,} | {on['far']} | {off['psnr']:.2f} | {on['psnr']:.2f} | "
            f"{off['photos']:.2f} | {on['photos']:.2f} | {off['seconds']:.1f} / {on['seconds']:.1f} |"
        )
        print(rows[-1], flush=True)
    text = "\n".join(
        [
            f"# The far set on a real capture: {fit.name}",
            "",
            f"Command: `python tools/bench_far_set.py {fit} --lams {lams}`",
            "",
            held_out_line(scene, eval_cams) + ". Codec alone (`--no-side-info`, decoded without "
            "refinement), encoded with the training cameras. Off: the contracted grid alone (attribute "
            "codec version 2); on: with the far set (version 3), as gspc writes it. PSNR of 8-bit renders "
            "at the held-out views.",
            "",
            "| lambda | bytes off | bytes on | on / off | POSN bytes off | POSN bytes on | far set "
            "| dB vs original, off | on | dB vs photos, off | on | encode s off / on |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    out.write_text(text)


if __name__ == "__main__":
    sys.exit(typer.run(main))
