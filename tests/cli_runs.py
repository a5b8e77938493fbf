"""Running the command line in-process, and the one-line error it must give for bad input: shared by
tests/test_cli.py, tests/test_gpu.py, tests/test_input_edges.py and tests/test_outputs.py."""

from typer.testing import CliRunner

from gspc.cli import app

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def assert_one_line_error(res, needle):
    """Exit 1 and one error line, last; anything before it is a progress line (stderr is not a terminal)."""
    assert res.exit_code == 1, res.output
    *before, last = res.output.strip().splitlines()
    assert "Traceback" not in res.output
    assert last.startswith("error:"), res.output
    assert all(line.startswith("gspc: ") for line in before), res.output
    assert needle.lower() in last.lower(), res.output
