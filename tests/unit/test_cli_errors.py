"""Errors by type at the command line: the project's input errors
(:class:`uavest.errors.InputError` and its subclasses) and ``OSError`` are one line and
exit 2; any other exception is an internal error (one line naming its type, exit 1, the
traceback with ``-v``), never "bad input"; no decision is taken on an exception's text."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

import uavest.cli as cli
import uavest.cli.bench as cli_bench
from uavest.errors import InputError
from uavest.ingest.types import IngestError, NoSamplesError
from uavest.scenarios import ScenarioError

ROOT = Path(__file__).resolve().parents[2]
REPO_LOG = ROOT / "logs" / "sim_200hz.tlog"  # committed with the repository


def _run(*argv: str, code: str | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-c", code, *argv] if code else [sys.executable, "-m", "uavest",
                                                            *argv]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)


# ------------------------------------------------------------------ real subprocesses


@pytest.mark.parametrize("argv,says", [
    (["bench", "ungm", "--runs", "0"], "--runs must be >= 1"),
    (["bench", "ungm", "--seed", "-1", "--runs", "1", "--steps", "2"], "seed"),
    (["replay", "/nonexistent.tlog"], "no such log file"),
])
def test_bad_input_in_a_subprocess_is_one_line_and_exit_2(argv, says):
    r = _run(*argv)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], r.stderr
    assert lines[0].startswith(f"uavest {argv[0]}: error: ")
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr


@pytest.mark.slow
def test_an_os_error_is_one_clear_line_and_exit_2(tmp_path):
    # the JSON's folder cannot be made: its parent is a file (NotADirectoryError et al.)
    f = tmp_path / "a_file"
    f.write_text("")
    r = _run("bench", "linear_cv", "--runs", "1", "--steps", "2", "--json",
             str(f / "sub" / "out.json"))
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("uavest bench: error: "), r.stderr
    assert "[Errno" not in lines[0] and str(f) in lines[0], lines[0]


# the command's function replaced in a real process (no hook in the package itself)
_BOOM = """
import sys
import uavest.cli as cli
def boom(args):
    raise RuntimeError("boom from a bug")
cli.cmd_list = boom
sys.exit(cli.main(sys.argv[1:]))
"""


def test_an_internal_error_in_a_subprocess_is_one_line_and_exit_1():
    r = _run("list", code=_BOOM)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert lines == ["uavest list: internal error: RuntimeError: boom from a bug "
                     "(run with -v for the traceback; please report)"], r.stderr


def test_verbose_shows_the_traceback_of_an_internal_error():
    r = _run("-v", "list", code=_BOOM)
    assert r.returncode == 1, r.stderr
    assert "Traceback (most recent call last)" in r.stderr
    assert ", in boom\n" in r.stderr and "in _call" in r.stderr  # down to the frame that raised
    last = r.stderr.strip().splitlines()[-1]
    assert last == ("uavest list: internal error: RuntimeError: boom from a bug "
                    "(please report)"), r.stderr


# ------------------------------------------------------------------ in-process, by type


@pytest.mark.parametrize("exc,code,head", [
    (RuntimeError("a bug"), 1, "internal error: RuntimeError: a bug"),
    (ValueError("a plain ValueError is ours"), 1,
     "internal error: ValueError: a plain ValueError is ours"),
    (TypeError("wrong type\nsecond line"), 1, "internal error: TypeError: wrong type"),
    (KeyError("k"), 1, "internal error: KeyError: 'k'"),
    (InputError("--x must be > 0"), 2, "error: --x must be > 0"),
    (ScenarioError("scenario: bad"), 2, "error: scenario: bad"),
    (IngestError("x.tlog: truncated"), 2, "error: x.tlog: truncated"),
    (FileNotFoundError(2, "No such file or directory", "out/x.json"), 2,
     "error: out/x.json: No such file or directory"),
    (ConnectionRefusedError(111, "Connection refused"), 2, "error: Connection refused"),
])
def test_the_exit_code_follows_the_type_not_the_text(monkeypatch, capsys, exc, code, head):
    def cmd(args):
        raise exc

    monkeypatch.setattr(cli_bench, "cmd_bench", cmd)  # the lazy entry point reads it
    assert cli.main(["bench", "linear_cv"]) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"uavest bench: {head}"), err
    assert ("please report" in err[0]) == (code == 1), err


def test_argparse_errors_are_unchanged(capsys):
    assert cli.main(["bench", "--runs", "notanint"]) == 2
    err = capsys.readouterr().err
    assert "usage: uavest bench" in err and "invalid int value" in err
    assert "internal error" not in err


def test_replay_decides_on_the_type_not_on_the_message(monkeypatch):
    """A ValueError that merely says "no samples" is not turned into the "no IMU samples
    could be read" input error; the engine's NoSamplesError is."""
    import uavest.apps.replay as rp

    def fake(text_or_type):
        def replay_samples(*a, **k):
            raise text_or_type
        return replay_samples

    monkeypatch.setattr(rp, "replay_samples", fake(ValueError("no samples in the stream")))
    with pytest.raises(ValueError) as ei:
        rp.replay(REPO_LOG)
    assert not isinstance(ei.value, InputError)
    monkeypatch.setattr(rp, "replay_samples", fake(NoSamplesError("anything")))
    with pytest.raises(IngestError, match="no IMU samples could be read"):
        rp.replay(REPO_LOG)


@pytest.mark.slow
def test_a_window_without_samples_is_an_input_error_exit_2():
    r = _run("replay", str(REPO_LOG), "--start", "1e9")
    assert r.returncode == 2, r.stderr
    assert "no IMU samples could be read in the window" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_the_command_line_raises_no_plain_value_error():
    """Every check of a command-line value raises InputError (exit 2), so that a plain
    ValueError reaching the top is one of ours."""
    bad = []
    for f in sorted((ROOT / "uavest" / "cli").glob("*.py")):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Raise) and node.exc is not None:
                e = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                if isinstance(e, ast.Name) and e.id == "ValueError":
                    bad.append(f"{f.name}:{node.lineno}")
    assert not bad, bad
