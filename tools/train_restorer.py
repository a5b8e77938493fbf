"""Train gspc's restorer (NAFNet) on data from tools/make_restorer_data.py.

    python tools/train_restorer.py /work/restorer_data /work/restorer_runs/small --steps 4000
    torchrun --nproc_per_node 2 tools/train_restorer.py DATA RUN ...   # DDP (gloo on CPU, nccl on GPU)

Each step draws random patches from the training views: input concat(I~, R~), target R, where R~
is one of the view's stored decodings of R (the encoder's planned JPEG XL distance or a grid of
others, picked at random) so one model serves every rate point. Loss: L1(R^, R) + ssim_weight *
(1 - SSIM(clamp(I~ + R^), I)) + lpips_weight * LPIPS (only when LPIPS weights are on disk:
--lpips-weights or $GSPC_LPIPS_WEIGHTS). AdamW, cosine learning rate after a linear warm-up.

Every epoch (--epoch-steps) the model restores the whole held-out views at the validation rate
point through gspc's own inference path (Restorer) and logs PSNR of I~ + R~ (side information
alone) and of the restored view, both clamped and quantised to 8 bits as the evaluator does.
RUN/log.csv gets one row per log interval; RUN/last.pt is the checkpoint (model, optimiser,
schedule, step, every rank's random state) from which a rerun resumes exactly; RUN/summary.json
holds the final validation over every rate point. --ship NAME writes the weights into gspc's
weights folder (gspc.restore.restorer.save_restorer).
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from pathlib import Path

import torch
import torch.distributed as dist
import torch.nn.functional as F
import typer
from lpips_vgg import LPIPS

from gspc.atomic import atomic_write
from gspc.metrics import ssim
from gspc.restore.data import load_view, read_manifest, validate
from gspc.restore.nafnet import NAFNet, count_parameters
from gspc.restore.restorer import save_restorer

LOG_FIELDS = "step epoch lr loss l1 ssim_term val_side_db val_restored_db val_gain_db s".split()


# ---------------------------------------------------------------------------------------------
# Data


def sample_batch(
    views: list[dict], batch: int, patch: int, gen: torch.Generator, min_activity: float = 1e-3
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(x (B,6,p,p), residual target (B,3,p,p), degraded (B,3,p,p)) of random patches.

    Patches where almost nothing went wrong (mean |R| below ``min_activity``, mostly empty
    background) are redrawn a few times so the batch is about the codec's errors.
    """
    xs, rs, ds = [], [], []

    def rand(n: int) -> int:
        return int(torch.randint(n, (1,), generator=gen))

    for _ in range(batch):
        for attempt in range(4):
            v = views[rand(len(views))]
            _, h, w = v["degraded"].shape
            ph, pw = min(patch, h), min(patch, w)
            y, x = rand(h - ph + 1), rand(w - pw + 1)
            r = v["residual"][:, y : y + ph, x : x + pw]
            if attempt == 3 or float(r.float().abs().mean()) >= min_activity:
                break
        k = rand(len(v["side"]))
        d = v["degraded"][:, y : y + ph, x : x + pw].float()
        s = v["side"][k][:, y : y + ph, x : x + pw].float()
        r = r.float()
        flips = rand(8)  # one of the 8 flips/transposes of the square
        if flips & 1:
            d, s, r = d.flip(-1), s.flip(-1), r.flip(-1)
        if flips & 2:
            d, s, r = d.flip(-2), s.flip(-2), r.flip(-2)
        if flips & 4 and ph == pw:
            d, s, r = d.transpose(-1, -2), s.transpose(-1, -2), r.transpose(-1, -2)
        if (ph, pw) != (patch, patch):  # views smaller than a patch: replicate-pad
            pad = (0, patch - d.shape[-1], 0, patch - d.shape[-2])
            d, s, r = (F.pad(t[None], pad, mode="replicate")[0] for t in (d, s, r))
        xs.append(torch.cat([d, s]))
        rs.append(r)
        ds.append(d)
    return torch.stack(xs), torch.stack(rs), torch.stack(ds)


# ---------------------------------------------------------------------------------------------
# Validation


# ---------------------------------------------------------------------------------------------
# Training


def lr_at(step: int, total: int, base: float, warmup: int, floor: float = 1e-2) -> float:
    if step < warmup:
        return base * (step + 1) / warmup
    t = min(1.0, (step - warmup) / max(1, total - warmup))
    return base * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * t)))


def _atomic_torch_save(obj, path: Path) -> None:
    atomic_write(path, lambda f: torch.save(obj, f))


def _ints(text: str) -> list[int]:
    return [int(v) for v in text.split(",") if v != ""]


def main(
    data_dir: Path = typer.Argument(..., help="folder written by make_restorer_data.py"),
    run_dir: Path = typer.Argument(..., help="checkpoints and logs (resumes from RUN/last.pt)"),
    steps: int = typer.Option(4000, help="total optimiser steps"),
    stop_after: int = typer.Option(0, help="stop this run after so many steps (0: run to --steps)"),
    batch: int = typer.Option(8, help="patches per step and process"),
    patch: int = typer.Option(96, help="patch side in pixels"),
    lr: float = typer.Option(1e-3),
    weight_decay: float = typer.Option(1e-4),
    warmup: int = typer.Option(100),
    ssim_weight: float = typer.Option(0.2, help="weight of 1 - SSIM(restored, original)"),
    lpips_weight: float = typer.Option(0.05, help="weight of LPIPS, used only when its weights exist"),
    lpips_weights: str = typer.Option("", help="LPIPS weights file/folder (default $GSPC_LPIPS_WEIGHTS)"),
    width: int = typer.Option(16),
    enc: str = typer.Option("1,1,1", help="NAFBlocks per encoder level"),
    middle: int = typer.Option(1),
    dec: str = typer.Option("1,1,1", help="NAFBlocks per decoder level"),
    epoch_steps: int = typer.Option(500, help="steps between validations and checkpoints"),
    log_every: int = typer.Option(50),
    val_rate: str = typer.Option("low", help="rate point validated every epoch"),
    seed: int = typer.Option(0),
    threads: int = typer.Option(1, help="torch threads per process"),
    device: str = typer.Option("cpu", help="cpu or cuda"),
    resume: bool = typer.Option(True, help="continue from RUN/last.pt when it exists"),
    ship: str = typer.Option("", help="at the end, save the weights under this restorer name"),
    weights_dir: str = typer.Option("", help="where --ship writes (default gspc/restore/weights)"),
) -> None:
    torch.set_num_threads(threads)
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    if world > 1:
        backend = "nccl" if device == "cuda" else "gloo"
        dist.init_process_group(backend)
    if device == "cuda":
        dev = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(dev)
    else:
        dev = torch.device("cpu")
    lead = rank == 0
    run_dir.mkdir(parents=True, exist_ok=True)

    entries = read_manifest(data_dir)
    train_views = [load_view(data_dir, e) for e in entries if e["split"] == "train"]
    val_views = [load_view(data_dir, e) for e in entries if e["split"] == "val"] if lead else []
    if not train_views:
        raise SystemExit(f"{data_dir} has no training views")
    config = {
        "in_channels": 6,
        "out_channels": 3,
        "width": width,
        "enc_blocks": _ints(enc),
        "middle_blocks": middle,
        "dec_blocks": _ints(dec),
        "predict_correction": True,
    }
    torch.manual_seed(seed)
    model = NAFNet(**config).to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay, betas=(0.9, 0.9))
    gen = torch.Generator().manual_seed(seed * 1000 + rank)
    step = 0
    ckpt_path = run_dir / "last.pt"
    if resume and ckpt_path.is_file():
        ck = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optim"])
        step = int(ck["step"])
        states = ck.get("gen_states", [])
        if len(states) == world:
            gen.set_state(states[rank])
        else:  # a different process count: fresh but distinct streams
            gen.manual_seed(seed * 1000 + rank + 7919 * step)
        if lead:
            print(f"resumed from {ckpt_path} at step {step}", flush=True)
    net = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model

    lpips_model = None
    if lpips_weight > 0 and (lpips_weights or os.environ.get("GSPC_LPIPS_WEIGHTS")):
        lpips_model = LPIPS.from_file(lpips_weights or None).to(dev)
    if lead:
        print(
            f"{len(train_views)} training views, {len(val_views)} validation views, "
            f"NAFNet {config} with {count_parameters(model)} parameters, world {world}, "
            f"LPIPS {'on' if lpips_model is not None else 'off (no weights on disk)'}",
            flush=True,
        )

    log_path = run_dir / "log.csv"
    if lead and not log_path.is_file():
        with open(log_path, "w", newline="") as f:
            csv.writer(f).writerow(LOG_FIELDS)

    def save(at: int) -> None:
        states = [gen.get_state()]
        if world > 1:
            states = [None] * world
            dist.all_gather_object(states, gen.get_state())
        if lead:
            ck = {"model": model.state_dict(), "optim": opt.state_dict(), "step": at, "gen_states": states}
            ck["config"] = json.dumps(config)
            _atomic_torch_save(ck, ckpt_path)

    def log(row: dict) -> None:
        with open(log_path, "a", newline="") as f:
            csv.writer(f).writerow([row.get(k, "") for k in LOG_FIELDS])

    end = steps if stop_after <= 0 else min(steps, step + stop_after)
    t0 = time.perf_counter()
    acc = {"loss": 0.0, "l1": 0.0, "ssim_term": 0.0, "n": 0}
    model.train()
    while step < end:
        cur_lr = lr_at(step, steps, lr, warmup)
        for g in opt.param_groups:
            g["lr"] = cur_lr
        x, r, d = (t.to(dev) for t in sample_batch(train_views, batch, patch, gen))
        r_hat = net(x)
        l1 = (r_hat - r).abs().mean()
        restored = (d + r_hat).clamp(0, 1).permute(0, 2, 3, 1)
        original = (d + r).clamp(0, 1).permute(0, 2, 3, 1)
        ssim_term = 1 - ssim(restored, original).mean()
        loss = l1 + ssim_weight * ssim_term
        if lpips_model is not None:
            loss = loss + lpips_weight * lpips_model(restored, original).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        acc["loss"] += loss.item()
        acc["l1"] += l1.item()
        acc["ssim_term"] += ssim_term.item()
        acc["n"] += 1
        row = None
        if lead and (step % log_every == 0 or step == end):
            n = max(1, acc["n"])
            row = {
                "step": step,
                "epoch": step / epoch_steps,
                "lr": f"{cur_lr:.3g}",
                "loss": f"{acc['loss'] / n:.6g}",
                "l1": f"{acc['l1'] / n:.6g}",
                "ssim_term": f"{acc['ssim_term'] / n:.6g}",
                "s": f"{time.perf_counter() - t0:.1f}",
            }
            acc = {"loss": 0.0, "l1": 0.0, "ssim_term": 0.0, "n": 0}
        if step % epoch_steps == 0 or step == end:
            save(step)
            if lead and val_views:
                v = validate(model, val_views, val_rate)
                row = row or {"step": step, "epoch": step / epoch_steps}
                row["s"] = f"{time.perf_counter() - t0:.1f}"
                for key, name in (
                    ("side", "val_side_db"),
                    ("restored", "val_restored_db"),
                    ("gain", "val_gain_db"),
                ):
                    row[name] = f"{v[key]:.4f}"
        if row is not None:
            log(row)
            print(", ".join(f"{k} {row[k]}" for k in LOG_FIELDS if k in row), flush=True)

    if lead and step >= steps:
        summary = {"steps": step, "config": config, "parameters": count_parameters(model), "validation": {}}
        for rate in sorted({v["entry"]["rate"] for v in val_views}):
            summary["validation"][rate] = validate(model, val_views, rate)
        summary["train_views"] = len(train_views)
        summary["train_scenes"] = sorted({v["entry"]["scene"] for v in train_views})
        summary["val_scenes"] = sorted({v["entry"]["scene"] for v in val_views})
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        print(json.dumps(summary["validation"], indent=1), flush=True)
        if ship:
            path = save_restorer(model.cpu(), config, ship, weights_dir or None)
            print(f"shipped {path}", flush=True)
    if world > 1:
        dist.barrier()
        dist.destroy_process_group()


if __name__ == "__main__":
    typer.run(main)
