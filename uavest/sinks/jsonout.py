"""The one strict-JSON writer of results.

JSON has no NaN or infinity. A value that could not be computed (a metric with no
samples to average: no reference overlap, no assigned track, no update) is written as
``null``, and the document's ``"nulls"`` list names every such place (a JSON pointer such
as ``/filters/ekf/nees_mean``) with the reason ``"not computable"``: no silent loss.
numpy scalars and arrays become numbers and lists.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

__all__ = ["clean", "dumps", "write_json"]


def clean(o, path: str = "", nulls: list | None = None):
    """``o`` with numpy values converted and non-finite floats replaced by None (their
    JSON pointers appended to ``nulls``)."""
    if isinstance(o, np.ndarray):
        o = o.tolist()
    elif isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        if nulls is not None:
            nulls.append(path or "/")
        return None
    if isinstance(o, dict):
        return {str(k): clean(v, f"{path}/{k}", nulls) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [clean(v, f"{path}/{i}", nulls) for i, v in enumerate(o)]
    return o


def dumps(doc: dict, indent: int | None = 2) -> str:
    """Strict JSON text of a result document (see the module docstring)."""
    nulls: list[str] = []
    out = clean(doc, "", nulls)
    if nulls and isinstance(out, dict):
        out["nulls"] = {p: "not computable" for p in nulls}
    return json.dumps(out, indent=indent, allow_nan=False)


def write_json(path: str | Path, doc: dict) -> Path:
    """Write ``doc`` as strict JSON to ``path`` (folders created); returns the path."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(dumps(doc) + "\n")
    return p
