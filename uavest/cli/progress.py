"""The command line's progress indicators: a tqdm bar on a terminal, one line per
stage otherwise."""

from __future__ import annotations

import sys

#: Seconds a run takes before :class:`LineProgress` prints anything.
PROGRESS_AFTER_S = 2.0


class LineProgress:
    """Progress when stderr is not a terminal (a log file, CI): one line per stage or
    every ``every`` s, only once the run has taken ``after`` s (a quick run prints
    nothing), and a last line at :meth:`close` if any was printed. The ``update`` /
    ``set_postfix_str`` / ``set_description`` / ``reset`` / ``close`` of a tqdm bar."""

    def __init__(self, total: int | None, desc: str, after: float = 2.0,
                 every: float = 5.0, file=None) -> None:
        import time

        self._clock = time.monotonic
        self.total, self.desc, self.after, self.every = total, desc, after, every
        self.file = file if file is not None else sys.stderr
        self.n, self.postfix = 0, ""
        self.t0 = self._clock()
        self.last: float | None = None  # when the last line was printed

    def _line(self, force: bool = False) -> None:
        now = self._clock()
        el = now - self.t0
        if el < self.after or (not force and self.last is not None
                               and now - self.last < self.every):
            return
        self.last = now
        of = f"/{self.total}" if self.total else ""
        post = f", {self.postfix}" if self.postfix else ""
        print(f"{self.desc}: {self.n}{of}{post} ({el:.0f} s)", file=self.file, flush=True)

    def update(self, n: int = 1) -> None:
        self.n += n
        self._line()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = s

    def set_description(self, desc: str, refresh: bool = True) -> None:
        """A new stage: one line for it (once the run has taken ``after`` s)."""
        self.desc = desc
        self._line(force=True)

    def reset(self, total: int | None = None) -> None:
        self.total, self.n = total, 0

    def close(self) -> None:
        self._line(force=True)  # a run that took ``after`` s ends with one line
        self.after = float("inf")


def progress(total: int | None, desc: str, enabled: bool | None = None,
             lines: bool = False):
    """A tqdm progress bar on stderr, only on a terminal (``enabled`` None) or when asked;
    otherwise, with ``lines``, a :class:`LineProgress` (one line per stage when stderr is
    not a terminal), else a silent stand-in with the same ``update``/``close``/
    ``set_postfix_str``."""
    on = sys.stderr.isatty() if enabled is None else enabled
    if lines and enabled is None and not on:
        return LineProgress(total, desc, after=PROGRESS_AFTER_S)
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=not on, leave=False, dynamic_ncols=True,
                file=sys.stderr)
