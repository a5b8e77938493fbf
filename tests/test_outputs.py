"""Outputs go where the user points (issue 26): a regular file is replaced atomically, a character device or a
named pipe is written as a stream and stays what it was, a trailing slash or a folder is refused in one line;
and GSPC_THREADS is checked in one line."""

import os
import stat
import threading

import pytest
import torch
from cli_runs import assert_one_line_error, run

from gspc import cli
from gspc.atomic import atomic_write_bytes, check_output_path
from gspc.errors import GspcError, InputError
from gspc.io import read_scene
from gspc.workers import default_workers

pytestmark = pytest.mark.skipif(os.name != "posix", reason="device nodes and named pipes are POSIX")


def _drain(path, sink: list[bytes]) -> threading.Thread:
    def read():
        with open(path, "rb") as f:
            sink.append(f.read())

    t = threading.Thread(target=read, daemon=True)
    t.start()
    return t


def test_a_named_pipe_gets_the_bytes_and_stays_a_pipe(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = _drain(fifo, got)
    atomic_write_bytes(fifo, b"hello pipe")
    reader.join(timeout=30)
    assert got == [b"hello pipe"]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]  # no temporary file left beside it


def test_dev_null_stays_a_device():
    before = os.stat(os.devnull)
    atomic_write_bytes(os.devnull, b"x" * 1000)
    after = os.stat(os.devnull)
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino and after.st_rdev == before.st_rdev


def test_a_link_to_a_file_stays_a_link(tmp_path):
    target = tmp_path / "real.bin"
    target.write_bytes(b"old")
    link = tmp_path / "link.bin"
    link.symlink_to(target)
    atomic_write_bytes(link, b"new")
    assert link.is_symlink() and target.read_bytes() == b"new"


@pytest.mark.parametrize("suffix", ["/", os.sep])
def test_trailing_slash_and_folders_are_refused(tmp_path, suffix):
    with pytest.raises(InputError, match="names a folder"):
        atomic_write_bytes(str(tmp_path / "name") + suffix, b"x")
    with pytest.raises(InputError, match="is a folder"):
        check_output_path(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_a_socket_is_refused(tmp_path):
    import socket

    path = tmp_path / "s.sock"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(path))
        with pytest.raises(InputError, match="neither"):
            atomic_write_bytes(path, b"x")
        assert stat.S_ISSOCK(os.stat(path).st_mode)


def test_cli_writes_to_dev_null_and_a_pipe(tmp_path, scene_file):
    res = run("convert", scene_file, "-o", os.devnull)
    assert res.exit_code == 0, res.output
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
    fifo = tmp_path / "out.ply"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = _drain(fifo, got)
    res = run("convert", scene_file, "-o", fifo)
    reader.join(timeout=60)
    assert res.exit_code == 0, res.output
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    copy = tmp_path / "copy.ply"
    copy.write_bytes(got[0])
    assert read_scene(copy).num_gaussians == read_scene(scene_file).num_gaussians


@pytest.mark.parametrize("command", ["convert", "encode", "decode"])
def test_cli_refuses_a_trailing_slash_before_any_work(tmp_path, scene_file, command):
    target = str(tmp_path / "name") + "/"
    assert_one_line_error(run(command, scene_file, "-o", target), "names a folder")
    assert not (tmp_path / "name").exists()


@pytest.mark.parametrize("value", ["0", "-1", "text", "1.5", " ", "1e3", "٣"])
def test_bad_thread_counts_are_one_line(value):
    if not value.strip():
        assert cli.thread_count(value) == cli.DEFAULT_THREADS
        return
    with pytest.raises(GspcError, match="GSPC_THREADS"):
        cli.thread_count(value)


@pytest.mark.parametrize("value", [str(2**40), "10000", "9" * 5000])
def test_huge_thread_counts_are_clamped_to_the_cores(value):
    assert cli.thread_count(value) == default_workers()


@pytest.mark.parametrize("value", ["0", "-1", "text", "1.5"])
def test_cli_reports_bad_thread_counts(monkeypatch, scene_file, value):
    monkeypatch.setenv("GSPC_THREADS", value)
    assert_one_line_error(run("info", scene_file), "GSPC_THREADS")


def test_cli_runs_with_a_huge_thread_count(monkeypatch, scene_file):
    before = torch.get_num_threads()
    monkeypatch.setenv("GSPC_THREADS", "10000")
    try:
        res = run("info", scene_file)
        assert res.exit_code == 0, res.output
        assert torch.get_num_threads() == default_workers()
    finally:
        torch.set_num_threads(before)


def test_output_to_stdout_in_a_pipe_is_only_the_file(tmp_path, scene_file):
    """`-o /dev/stdout` in a pipe: stdout carries the PLY alone; the report goes to stderr."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(repo), "GSPC_THREADS": "1"}
    cmd = [sys.executable, "-m", "gspc.cli", "convert", str(scene_file), "-o", "/dev/stdout"]
    res = subprocess.run(cmd, capture_output=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr.decode()
    copy = tmp_path / "copy.ply"
    copy.write_bytes(res.stdout)
    n = read_scene(scene_file).num_gaussians
    assert read_scene(copy).num_gaussians == n
    assert f"wrote {n} Gaussians".encode() in res.stderr and b"wrote" not in res.stdout
