"""tools/bench_ray.py's report: every run's row with its peaks, identical files said so, and the scaling model
from the tasks' times."""

from __future__ import annotations

from bench_ray import RUNS, makespan, report


def _row(name: str, sha: str, cpu: bool, peaks: bool = True) -> dict:
    tiles = [
        {"given": 100, "coded": 90, "bytes": 1000, "seconds": 10.0, "side": "none (no view sampled)"}
        | ({"cpu": 9.0} if cpu else {}),
        {"given": 50, "coded": 40, "bytes": 500, "seconds": 4.0, "side": None}
        | ({"cpu": 3.0} if cpu else {}),
    ]
    row = {
        "name": name,
        "sha256": sha,
        "decoded_sha256": "d",
        "encode_wall_inside": 15.0,
        "executor_start": 0.0,
        "stages": {"tiles": 14.0},
        "decode_wall_inside": 1.0,
        "bytes": 1600,
        "plan_seconds": 0.1,
        "tiles": tiles,
        "load": (1.0, 2.0),
        "cpu": 30.0,  # the run's, every process
    }
    if peaks:
        row["peak_mb"] = {"encode": [2048.0, 1024.0], "decode": [512.0, 256.0]}
    return row


def test_makespan_orders_tasks_on_the_first_free_worker():
    assert makespan([4.0, 3.0, 2.0, 1.0], 1) == 10.0
    assert makespan([4.0, 3.0, 2.0, 1.0], 2) == 5.0  # 4+1 and 3+2
    assert makespan([4.0, 3.0], 8) == 4.0


def test_report_states_peaks_side_information_and_identity():
    rows = [_row(RUNS[0][0], "a", cpu=True), _row(RUNS[1][0], "a", cpu=False, peaks=False)]
    text = report(rows, "scene", 262144, "a machine")
    assert "| 2,048 (1,024) | 512 (256) |" in text
    assert "not sampled" in text  # a row from before the peaks were sampled
    assert "Every file identical: yes" in text
    assert "none (no view sampled)" in text and "not weighed" in text
    assert "| 2 | " in text and "CPU s, 1 worker" in text


def test_report_says_when_a_file_differs():
    rows = [_row(RUNS[0][0], "a", cpu=True), _row(RUNS[2][0], "b", cpu=False)]
    text = report(rows, "scene", 262144, "a machine")
    assert "Every file identical: NO" in text and "| NO |" in text
