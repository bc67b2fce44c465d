"""The result store: one strict-JSON file per task, ``OUT/results/<key>.json``.

Files are written by the driver only (workers may be on other machines), to a temporary
name in the same folder and then renamed (atomic on POSIX): an interrupted run leaves
complete result files or none, never half of one. Only ``*.json`` counts as a result;
leftover ``.tmp-*`` files (a run killed during a write) are removed on the next start.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..sinks.jsonout import dumps

__all__ = ["ResultStore"]


class ResultStore:
    def __init__(self, out: str | Path) -> None:
        self.root = Path(out)
        self.dir = self.root / "results"
        self.dir.mkdir(parents=True, exist_ok=True)
        for stale in self.dir.glob(".tmp-*"):
            stale.unlink(missing_ok=True)

    def path(self, key: str) -> Path:
        return self.dir / f"{key}.json"

    def load(self, key: str) -> dict | None:
        """The stored document of ``key``, or None (absent or unreadable)."""
        p = self.path(key)
        try:
            return json.loads(p.read_text())
        except (OSError, ValueError):
            return None

    def save(self, key: str, doc: dict) -> Path:
        """Write ``doc`` atomically (temp file + rename); returns the final path."""
        write_atomic(self.path(key), dumps(doc) + "\n")
        return self.path(key)


def write_atomic(path: Path, text: str) -> None:
    """``text`` to ``path`` through a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".tmp-{path.name}-{os.getpid()}"
    try:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
