"""The one table renderer: the fixed-width metric tables the command line and
``uavest evaluate``'s summary print (a sink-layer helper, so every layer above can use it)."""

from __future__ import annotations

import math


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "-"
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
