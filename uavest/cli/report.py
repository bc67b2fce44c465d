"""The one table renderer of the command line (and its progress indicator)."""

from __future__ import annotations

import math
import sys


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


def progress(total: int | None, desc: str, enabled: bool | None = None):
    """A tqdm progress bar on stderr, only on a terminal (``enabled`` None) or when asked;
    otherwise a silent stand-in with the same ``update``/``close``/``set_postfix_str``."""
    on = sys.stderr.isatty() if enabled is None else enabled
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=not on, leave=False, dynamic_ncols=True,
                file=sys.stderr)
