"""One tiled encode (and its decode) on 1 local worker, 2 local processes, a 2-CPU local Ray instance and a
2-worker local Dask distributed cluster: wall and CPU seconds, bytes identical, per-task times and sizes, and
the scaling they predict (bench/ray.md).

    nice -n 10 python tools/bench_ray.py --scene /work/district_small/district_200000 --tile-size 65536 \\
        -o bench/ray.md

Every run is a fresh process (``--child``), sampled with every process below it (Ray's GCS, raylet and
workers included) for wall and CPU seconds. The child opens the executor itself, so its start is timed on
its own, then codes the scene as ``gspc encode`` does (gspc/pipeline.py encode_rows) with the scene
folder's cameras and the preset's options, and reports each tile's Gaussians, bytes and seconds. Ray runs
twice: each worker reading its tile from the file, and the driver shipping each tile's rows as an object
reference (``--ship-inputs``). Dask (``pip install 'dask[distributed]'``, the [tools] extra) runs the same
task functions through an executor of this bench's own (``DaskExecutor``: gspc itself runs on local
processes or Ray), to measure whether it would fit better; its decode runs on 2 local processes (gspc's
decode takes no executor from outside). The scaling model is ordered list scheduling of the measured
1-worker task times (a task goes to the first free worker, in task order, as the executors hand them out),
plus the driver's serial part and the executor's start.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import subprocess
import sys
import time
from contextlib import nullcontext
from pathlib import Path

from bench_tiles import _sample, _tree

REPO = Path(__file__).resolve().parent.parent
RUNS = (  # name, workers, ray, ship inputs
    ("1 local worker", 1, None, False),
    ("2 local processes", 2, None, False),
    ("Ray, 2 CPUs, workers read the file", 2, "auto", False),
    ("Ray, 2 CPUs, rows shipped as object refs", 2, "auto", True),
    ("Dask, 2 workers, workers read the file", 2, "dask", False),
    ("Dask, 2 workers, rows shipped with each task", 2, "dask", True),
)


def dask_executor(workers: int):
    """An executor (gspc/workers.py) on a local Dask distributed cluster of ``workers`` one-thread worker
    processes; its tasks run as gspc's Ray tasks do (one thread, GSPC_THREADS=1)."""
    from distributed import Client, LocalCluster

    from gspc.workers import Executor, _call, _init_worker

    def task(fn, job):
        _init_worker()
        return _call(fn, job)

    class DaskExecutor(Executor):
        def __init__(self) -> None:
            self.slots = workers
            self.cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            self.client = Client(self.cluster)

        def describe(self) -> str:
            return f"a local Dask cluster ({workers} workers)"

        def _submit(self, fn, job):
            return self.client.submit(task, fn, job, pure=False)

        def _result(self, handle):
            return handle.result()

        def _cancel(self, handle) -> None:
            handle.cancel()

        def close(self) -> None:
            self.client.close()
            self.cluster.close()

    return DaskExecutor()


def child(spec: dict) -> dict:
    """One encode and decode as the spec says (in this process); what they did."""
    from gspc.atomic import atomic_write_bytes
    from gspc.encoder.prepare import codec_params
    from gspc.encoder.tiles import plan_tiles
    from gspc.io.camera_files import load_cameras
    from gspc.options import DecodeOptions, EncodeOptions
    from gspc.pipeline import Report, decode, encode_rows, large_ply
    from gspc.workers import open_executor

    cpu: list[float] = []
    if spec["workers"] == 1 and spec["ray"] is None:  # in this process: each task's CPU seconds too
        import gspc.encoder.tiles as tiles

        code_tile = tiles.code_tile

        def timed(job):
            c0 = time.process_time()
            try:
                return code_tile(job)
            finally:
                cpu.append(time.process_time() - c0)

        tiles.code_tile = timed
    t0 = time.perf_counter()
    scene = Path(spec["scene"])
    dask = spec["ray"] == "dask"
    ray = None if dask else spec["ray"]
    opts = EncodeOptions(
        tile_size=spec["tile_size"],
        workers=spec["workers"],
        ray=ray,
        ship_inputs=spec["ship"],
        lam=spec.get("lam"),
    )
    opts.validate()
    cameras = load_cameras(scene / "cameras.json")
    rows = large_ply(scene / "point_cloud.ply", opts)
    assert rows is not None, "a scene larger than one tile"
    s0 = time.perf_counter()
    with nullcontext(dask_executor(opts.workers)) if dask else open_executor(opts.workers, opts.ray) as ex:
        start = time.perf_counter() - s0
        rep = Report()
        data = encode_rows(rows, cameras, opts, None, rep, ex)
        c0 = time.perf_counter()
    close = time.perf_counter() - c0
    out = Path(spec["out"])
    atomic_write_bytes(out, data)
    wall = time.perf_counter() - t0
    p0 = time.perf_counter()
    precision = codec_params(opts).position_precision
    plan = plan_tiles(rows.positions(), rows.log_scales(), precision, opts.tile_size)
    plan_s = time.perf_counter() - p0
    Path(spec["phase"]).write_text("decode")  # the sampler's peaks from here on are the decode's
    d0 = time.perf_counter()
    decoded = out.with_suffix(".ply")
    dec = decode(out, decoded, DecodeOptions(workers=spec["workers"], ray=ray))
    decode_wall = time.perf_counter() - d0
    return {
        "ran_on": rep.decisions.ran_on,
        "bytes": len(data),
        "sha256": hashlib.sha256(data).hexdigest(),
        "decoded_sha256": hashlib.sha256(decoded.read_bytes()).hexdigest(),
        "encode_wall_inside": wall,
        "executor_start": start,
        "executor_close": close,
        "stages": rep.seconds,
        "plan_seconds": plan_s,
        "decode_wall_inside": decode_wall,
        "decode_stages": dec.seconds,
        "tiles": [
            {"given": t.given, "coded": t.tile.n, "bytes": t.num_bytes, "seconds": t.seconds}
            | {"side": None if t.side is None else t.side.reason}
            | ({"cpu": cpu[k]} if cpu else {})
            for k, t in enumerate(rep.decisions.tiles)
        ],
        "plan_tiles": len(plan.rows),
    }


def run_child(spec: dict, log: Path) -> dict:
    """``spec`` in a fresh process, sampled with everything below it every fifth of a second: CPU seconds,
    and the peak resident memory of all its processes together and of the largest one, for the encode and
    for the decode apart (MB)."""
    env = dict(os.environ, GSPC_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), str(REPO / "tools"), env.get("PYTHONPATH", "")])
    result = log.with_suffix(".child.json")
    result.unlink(missing_ok=True)
    phase = log.with_suffix(".phase")
    phase.unlink(missing_ok=True)
    spec = dict(spec, phase=str(phase))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", json.dumps(spec)]
    cmd += ["--result", str(result)]
    cpu: dict[int, float] = {}
    peaks = {"encode": [0, 0], "decode": [0, 0]}  # kB: all processes together, the largest one
    load = os.getloadavg()[0]
    with open(log, "ab") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=out)
        while proc.poll() is None:
            rss = []
            for p in _tree(proc.pid):
                s = _sample(p)
                if s is not None:
                    cpu[p] = s[1]
                    rss.append(s[0])
            peak = peaks["decode" if phase.exists() else "encode"]
            peak[0] = max(peak[0], sum(rss))
            peak[1] = max(peak[1], max(rss, default=0))
            time.sleep(0.2)
        wall = time.perf_counter() - t0
    if proc.returncode:
        raise SystemExit(f"{spec['name']} failed; see {log}")
    row = json.loads(result.read_text())
    row.update(name=spec["name"], wall=wall, cpu=sum(cpu.values()), processes=len(cpu))
    row.update(peak_mb={k: [v / 1024 for v in kb] for k, kb in peaks.items()})
    row.update(load=(load, os.getloadavg()[0]))
    return row


def makespan(times: list[float], workers: int) -> float:
    """Ordered list scheduling: each task, in order, on the worker that frees first."""
    free = [0.0] * workers
    for t in times:
        k = min(range(workers), key=free.__getitem__)
        free[k] += t
    return max(free)


def _load(row: dict) -> str:
    return f"{row['load'][0]:.1f}, {row['load'][1]:.1f}" if "load" in row else "not sampled"


def _peaks(row: dict, phase: str) -> str:
    if "peak_mb" not in row:
        return "not sampled"
    total, largest = row["peak_mb"][phase]
    return f"{total:,.0f} ({largest:,.0f})"


def report(rows: list[dict], scene: str, tile_size: int, machine: str) -> str:
    base = next((r for r in rows if r["name"] == RUNS[0][0]), rows[0])  # 1 worker, where it ran
    same = all(r["sha256"] == base["sha256"] for r in rows)
    same_decoded = all(r["decoded_sha256"] == base["decoded_sha256"] for r in rows)
    lines = [
        f"## {scene}, tiles of {tile_size:,}",
        "",
        f"Machine: {machine}. Every run a fresh process at nice 10, each task on one thread. Encode wall:",
        "reading, the executor's start, coding the tiles, writing the file. CPU: every process of the run",
        "(Ray's GCS, raylet and workers included) from Python's start to the end of the decode after the",
        "encode. Decode wall: the file decoded to a PLY on the same workers (on Ray, a second instance's",
        "start included; Dask's on 2 local processes). The tiles stage plans the tiles and codes them.",
        "",
        "| run | load avg at start, end | encode wall s | CPU s (all processes) | executor start s "
        "| tiles stage s | decode wall s | peak MB encode: all (largest) | decode: all (largest) "
        f"| file bytes | same bytes as {base['name']} | decoded PLY the same |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['name']} | {_load(r)} | {r['encode_wall_inside']:.1f} | "
            f"{r['cpu']:.0f} | {r['executor_start']:.1f} | "
            f"{r['stages'].get('tiles', 0):.1f} | {r['decode_wall_inside']:.1f} | {_peaks(r, 'encode')} | "
            f"{_peaks(r, 'decode')} | {r['bytes']:,} | "
            f"{'yes' if r['sha256'] == base['sha256'] else 'NO'} | "
            f"{'yes' if r['decoded_sha256'] == base['decoded_sha256'] else 'NO'} |"
        )
    lines += ["", f"Every file identical: {'yes' if same else 'NO'}; every decode identical: "
              f"{'yes' if same_decoded else 'NO'}.", ""]  # fmt: skip
    has_cpu = "cpu" in base["tiles"][0]
    what = "; and its CPU seconds in the 1-worker run:" if has_cpu else ":"
    lines += [f"Per task (tile), wall seconds of its own work in each run (inside the task){what}", ""]
    names = [r["name"] for r in rows] + (["CPU s, 1 worker"] if has_cpu else [])
    lines += ["| tile | Gaussians | coded | bytes | " + " | ".join(names) + " | its side information |"]
    lines += ["|" + "---:|" * (4 + len(names)) + "---|"]
    for k, t in enumerate(base["tiles"]):
        secs = [f"{r['tiles'][k]['seconds']:.1f}" for r in rows] + ([f"{t['cpu']:.1f}"] if has_cpu else [])
        side = t.get("side") or "not weighed"
        cells = [f"{k}", f"{t['given']:,}", f"{t['coded']:,}", f"{t['bytes']:,}", *secs, side]
        lines.append("| " + " | ".join(cells) + " |")
    # A task's CPU seconds are what it takes on a core of its own; its wall seconds here include the
    # other sessions' share of the cores.
    times = [t["cpu" if has_cpu else "seconds"] for t in base["tiles"]]
    serial = base["encode_wall_inside"] - base["stages"].get("tiles", 0) + base["plan_seconds"]
    lines += [
        "",
        f"Model (from the {base['name']} run): {len(times)} tasks of {min(times):.0f}-{max(times):.0f} "
        f"{'CPU ' if has_cpu else 'wall '}s ({sum(times):.0f} s in all); the driver's serial part "
        f"{serial:.1f} s "
        f"(reading the positions, planning the tiles {base['plan_seconds']:.1f} s, packing and writing). "
        "Predicted encode wall on cores of its own (driver + ordered list scheduling of the tasks), without "
        "the executor's start:",
        "",
        "| workers | predicted s | speed-up over 1 |",
        "|---:|---:|---:|",
    ]
    one = serial + makespan(times, 1)
    for w in (1, 2, 4, 16, 64):
        t = serial + makespan(times, w)
        lines.append(f"| {w} | {t:.0f} | {one / t:.2f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=Path("/work/district_small/district_200000"))
    ap.add_argument("--tile-size", type=int, default=1 << 16)
    ap.add_argument("--lam", type=float, default=None, help="this lambda (default: the preset)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_ray"))
    ap.add_argument("--runs", default=",".join(str(k) for k in range(len(RUNS))), help="indices into RUNS")
    ap.add_argument("-o", "--out", type=Path, default=None, help="append the report here (default: print)")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--result", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        args.result.write_text(json.dumps(child(json.loads(args.child))))
        return
    args.work.mkdir(parents=True, exist_ok=True)
    # The compiled kernels first (gspc/jit.py), so that no run pays for compiling them.
    warm = "from gspc.jit import compile_kernels; compile_kernels(None, encoder=True)"
    subprocess.run([sys.executable, "-c", warm], check=True, env=dict(os.environ, PYTHONPATH=str(REPO)))
    load = os.getloadavg()
    rows = []
    for k in (int(x) for x in args.runs.split(",")):
        name, workers, ray, ship = RUNS[k]
        spec = dict(
            name=name,
            scene=str(args.scene),
            tile_size=args.tile_size,
            workers=workers,
            ray=ray,
            ship=ship,
            lam=args.lam,
            out=str(args.work / f"{args.scene.name}-{k}.gspc"),
        )
        row = run_child(spec, args.work / "runs.log")
        print(json.dumps(row), flush=True)
        with open(args.work / "rows.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")
        rows.append(row)
    after = os.getloadavg()
    machine = (
        f"{platform.node()}, {os.cpu_count()} CPUs, load average {load[0]:.1f} at start and {after[0]:.1f} "
        "at the end (other sessions' jobs share the cores)"
    )
    text = report(rows, args.scene.name, args.tile_size, machine)
    if args.out:
        with open(args.out, "a") as f:
            f.write("\n" + text)
    print(text)


if __name__ == "__main__":
    main()
