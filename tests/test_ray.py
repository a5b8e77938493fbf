"""Tasks on Ray and on local processes (issue 52, gspc/workers.py): a tiled file and its decode are the same
bytes on a small local Ray instance (2 CPUs) as on local processes; a task that raises or a worker that dies
is one line naming the task; a missing Ray or an address that does not answer is one line. The tests that
need Ray skip cleanly where it is not installed (``pip install 'gspc[ray]'``)."""

import logging
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_runs import assert_one_line_error, run
from test_tiles import QUICK, scene

from gspc.errors import DeviceError, GspcError, InputError
from gspc.io import write_ply
from gspc.options import DecodeOptions, EncodeOptions, check_ray
from gspc.pipeline import decode, encode, encode_scene
from gspc.workers import (
    CONNECT_SECONDS,
    LocalProcesses,
    TaskFailure,
    check_ray_address,
    import_ray,
    open_executor,
    run_tasks,
)

ROOT = Path(__file__).resolve().parent.parent
# The quick options as command-line flags (tests/test_tiles.py QUICK).
QUICK_FLAGS = [
    "--tile-size",
    QUICK["tile_size"],
    "--views",
    QUICK["synth_views"],
    "--max-side",
    QUICK["max_side"],
]
QUICK_FLAGS += ["--no-removal-search", "--tune-iterations", 0]


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """A scene of three tiles as a PLY, and its file coded on this process."""
    d = tmp_path_factory.mktemp("ray")
    src, out = d / "in.ply", d / "local.gspc"
    write_ply(scene(), src)
    encode(src, out, opts=EncodeOptions(**QUICK, workers=1))
    return src, out


@pytest.fixture(scope="module")
def ray_instance():
    """A small local Ray instance (2 CPUs) the module's runs share: ``--ray auto`` uses the instance this
    process is connected to."""
    ray = pytest.importorskip("ray")
    ray.init(
        address="local",
        num_cpus=2,
        num_gpus=0,
        object_store_memory=256 << 20,
        include_dashboard=False,
        log_to_driver=False,
        logging_level=logging.ERROR,
    )
    yield ray
    ray.shutdown()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --- without Ray ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("value", ["nowhere", "host:0", "host:99999", ":6379", "a b:6379", 6379])
def test_bad_ray_values_are_refused_in_one_line(value):
    with pytest.raises(InputError, match="--ray"):
        check_ray(value)
    assert check_ray("auto") == "auto" and check_ray(" 10.0.0.1:6379") == "10.0.0.1:6379"
    assert check_ray("ray://head:10001") == "ray://head:10001"


def test_a_missing_ray_is_one_line_naming_the_extra(local, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails as where it is not installed
    with pytest.raises(DeviceError, match=r"gspc\[ray\]"):
        import_ray()
    src, _ = local
    res = run("encode", src, "-o", tmp_path / "o.gspc", *QUICK_FLAGS, "--ray", "auto")
    assert_one_line_error(res, "pip install 'gspc[ray]'")
    assert not (tmp_path / "o.gspc").exists()


def test_an_address_nothing_answers_at_is_one_line_at_once():
    t0 = time.perf_counter()
    with pytest.raises(DeviceError, match="nothing answers"):
        check_ray_address(f"127.0.0.1:{_free_port()}")
    assert time.perf_counter() - t0 < CONNECT_SECONDS + 1


def _value(v) -> str:
    return f"value {v!r}"


def test_a_task_that_raises_is_named_and_a_batch_goes_on():
    names = _value
    with pytest.raises(InputError, match="^value 'x': --ray"):
        list(run_tasks(check_ray, ["auto", "x", None], 1, names, 3))
    with open_executor(1) as ex:
        out = list(ex.map(check_ray, ["auto", "x", None], names, 3, keep_going=True))
    assert (
        out[0] == "auto" and out[2] is None and isinstance(out[1], TaskFailure) and "value 'x'" in out[1].name
    )


@pytest.mark.slow
def test_a_local_worker_that_dies_is_one_line_and_the_pool_starts_again():
    ex = LocalProcesses(2)
    try:
        with pytest.raises(GspcError, match="task 3: a worker process died"):
            list(ex.map(os._exit, [3], lambda j: f"task {j}", 1))
        out = list(ex.map(os._exit, [4], lambda j: f"task {j}", 1, keep_going=True))
        assert isinstance(out[0], TaskFailure) and "died" in out[0].message
        assert list(ex.map(abs, [-1, -2], str, 2)) == [1, 2]  # a fresh pool
    finally:
        ex.close()


# --- on a local Ray instance ---------------------------------------------------------------------------


def test_ray_writes_the_local_bytes(ray_instance, local, tmp_path):
    src, out = local
    on_ray = tmp_path / "ray.gspc"
    rep = encode(src, on_ray, opts=EncodeOptions(**QUICK, ray="auto"))
    assert on_ray.read_bytes() == out.read_bytes()
    assert "Ray" in rep.info["tiles"], rep.info["tiles"]
    shipped = tmp_path / "shipped.gspc"  # each tile's rows read here and sent as an object reference
    encode(src, shipped, opts=EncodeOptions(**QUICK, ray="auto", ship_inputs=True))
    assert shipped.read_bytes() == out.read_bytes()


def test_ray_codes_a_scene_in_memory_as_local_workers_do(ray_instance):
    small = scene(2100, seed=5)
    local, _ = encode_scene(small, opts=EncodeOptions(**QUICK, workers=1))
    remote, _ = encode_scene(small, opts=EncodeOptions(**QUICK, ray="auto"))
    assert remote == local


def test_ray_decodes_the_local_bits(ray_instance, local, tmp_path):
    _, out = local
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    decode(out, a, DecodeOptions(workers=1))
    rep = decode(out, b, DecodeOptions(ray="auto"))
    assert a.read_bytes() == b.read_bytes() and "Ray" in rep.info["tiles"]


def test_a_ray_task_that_raises_or_dies_is_one_line(ray_instance):
    with open_executor(None, "auto") as ex:
        with pytest.raises(InputError, match="^value 'x': --ray"):
            list(ex.map(check_ray, ["auto", "x"], _value, 2))
        out = list(ex.map(check_ray, ["x", "auto"], str, 2, keep_going=True))
        assert isinstance(out[0], TaskFailure) and out[1] == "auto"
        with pytest.raises(GspcError, match="task 3: a Ray worker died"):
            list(ex.map(os._exit, [3], lambda j: f"task {j}", 1))
        assert list(ex.map(abs, [-1, -2], str, 2)) == [1, 2]  # the instance goes on
    assert ray_instance.is_initialized()  # an instance the run did not start is left running


def test_a_port_that_answers_but_is_not_ray_is_one_line(monkeypatch):
    import gspc.workers as workers

    monkeypatch.setattr(workers, "ANSWER_SECONDS", 3.0)
    with socket.socket() as server:  # accepts connections and says nothing
        server.bind(("127.0.0.1", 0))
        server.listen()
        t0 = time.perf_counter()
        with pytest.raises(DeviceError, match="not as a Ray cluster|not a Ray cluster"):
            check_ray_address(f"127.0.0.1:{server.getsockname()[1]}")
    assert time.perf_counter() - t0 < CONNECT_SECONDS + 3.0 + 5


@pytest.mark.slow
def test_the_command_line_starts_and_stops_its_own_instance(local, tmp_path):
    pytest.importorskip("ray")
    src, out = local
    res = subprocess.run(
        [sys.executable, "-m", "gspc.cli", "encode", src, "-o", tmp_path / "cli.gspc", *map(str, QUICK_FLAGS)]
        + ["--ray", "auto", "--workers", "2"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=str(ROOT), GSPC_THREADS="1"),
        timeout=600,
    )
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "cli.gspc").read_bytes() == out.read_bytes()
    assert "a local Ray instance (2 CPUs)" in res.stdout
    # Ray's own logs stay out of the user's terminal: every stderr line is gspc's
    assert all(line.startswith("gspc: ") for line in res.stderr.splitlines() if line.strip()), res.stderr
