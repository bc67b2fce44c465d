"""The layer list of ``uavest/__init__.py`` as import-linter contracts (``pyproject.toml``,
``[tool.importlinter]``): the checked tree keeps them, and the same check breaks on a
copy of the package with one back edge added (so the contract can fail). Skipped with the
reason when import-linter (the ``test`` extra) is not installed."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LINT = shutil.which("lint-imports")
pytestmark = pytest.mark.skipif(
    LINT is None, reason="import-linter not installed (pip install -e '.[test]')")


def _lint(root: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(root)}  # this tree's package, not an install
    return subprocess.run([LINT, "--no-cache", "--no-logo"], cwd=root, env=env,
                          capture_output=True, text=True, timeout=120)


def test_the_package_keeps_its_layers():
    r = _lint(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "0 broken" in r.stdout


def test_a_back_edge_breaks_the_layers(tmp_path):
    shutil.copytree(ROOT / "uavest", tmp_path / "uavest",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    # the geometry layer reaching up into the engine: the kind of edge the contract forbids
    (tmp_path / "uavest" / "geometry" / "_back_edge.py").write_text(
        "from ..engine.records import Step  # noqa: F401\n")
    r = _lint(tmp_path)
    assert r.returncode != 0, r.stdout
    assert "uavest.geometry is not allowed to import uavest.engine" in r.stdout
