"""Plain-text tables and JSON output for benchmark results."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        a = abs(v)
        if a != 0 and (a >= 1e5 or a < 1e-3):
            return f"{v:.3g}"
        return f"{v:.3f}" if a < 100 else f"{v:.1f}"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def table(rows: dict[str, dict], columns: list[str], first: str = "filter") -> str:
    """Fixed-width table: one row per key of ``rows``, the given metric columns."""
    head = [first] + columns
    body = [[name] + [_fmt(r.get(c)) for c in columns] for name, r in rows.items()]
    widths = [max(len(x) for x in col) for col in zip(head, *body, strict=True)]
    line = lambda cells: "  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True)))  # noqa: E731,E501
    return "\n".join([line(head), line(["-" * w for w in widths])] + [line(b) for b in body])


def write_json(path: str | Path, doc: dict) -> None:
    """Write ``doc`` as JSON (NaN/inf become null so the file is strict JSON)."""

    def clean(o):
        if isinstance(o, float) and not math.isfinite(o):
            return None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, list | tuple):
            return [clean(v) for v in o]
        return o

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(clean(doc), indent=2) + "\n")


class Progress:
    """A one-line progress indicator on stderr, only when stderr is a terminal."""

    def __init__(self, enabled: bool | None = None) -> None:
        self.enabled = sys.stderr.isatty() if enabled is None else enabled

    def __call__(self, label: str, i: int, n: int) -> None:
        if not self.enabled:
            return
        w = 30
        done = int(w * i / n)
        sys.stderr.write(f"\r{label[:28]:28s} [{'#' * done}{'.' * (w - done)}] {i}/{n}")
        if i == n:
            sys.stderr.write("\n")
        sys.stderr.flush()
