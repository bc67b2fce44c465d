"""The command line's progress indicator."""

from __future__ import annotations

import sys


def progress(total: int | None, desc: str, enabled: bool | None = None):
    """A tqdm progress bar on stderr, only on a terminal (``enabled`` None) or when asked;
    otherwise a silent stand-in with the same ``update``/``close``/``set_postfix_str``."""
    on = sys.stderr.isatty() if enabled is None else enabled
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=not on, leave=False, dynamic_ncols=True,
                file=sys.stderr)
