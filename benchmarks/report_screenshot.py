"""Screenshot of a report page with headless Chromium (the check that the self-contained
HTML renders with no network).

    python benchmarks/report_screenshot.py [RUN.mcap] [--out DIR]

Without a recording it records a replay of ``../shared/logs/vtol.tlog`` (up to
t = 700 s) first. Writes ``<DIR>/<stem>.html`` (via :func:`uavest.report.write_report`)
and ``<DIR>/<stem>.screenshot.png`` (1400 x 3000), prints their paths and a check that
the screenshot is not blank. Exit status 0 when the screenshot looks like a rendered page.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from _shared_logs import SHARED_LOGS  # noqa: E402

VTOL = SHARED_LOGS / "vtol.tlog"


def chromium() -> str | None:
    """Path of a Chromium binary, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    return None


def screenshot(html: Path, png: Path, size: str = "1400,3000") -> None:
    """Render ``html`` (a local file) to ``png`` with headless Chromium, no network."""
    exe = chromium()
    if exe is None:
        raise RuntimeError("chromium is not installed (apt-get install -y chromium)")
    with tempfile.TemporaryDirectory() as prof:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu",
               "--disable-background-networking", "--disable-component-update",
               "--disable-sync", "--no-first-run", f"--user-data-dir={prof}",
               f"--screenshot={png}", f"--window-size={size}",
               html.resolve().as_uri()]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       timeout=180)


def blank_check(png: Path) -> dict:
    """Simple statistics of a screenshot: share of non-white pixels and of coloured
    (filter-coloured) pixels."""
    import matplotlib.image as mpimg
    import numpy as np

    im = mpimg.imread(str(png))[..., :3]
    nonwhite = float(np.mean(im.min(axis=2) < 0.9))
    sat = im.max(axis=2) - im.min(axis=2)
    coloured = float(np.mean(sat > 0.3))
    return {"height": im.shape[0], "width": im.shape[1], "nonwhite": nonwhite,
            "coloured": coloured}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", nargs="?")
    ap.add_argument("--out", default="report_out")
    args = ap.parse_args(argv)
    from uavest.report import write_report

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rec = Path(args.recording) if args.recording else out / "vtol.mcap"
    if not args.recording:
        from uavest.apps.replay import ReplayConfig, replay
        from uavest.sinks.mcap import McapSink

        replay(VTOL, ReplayConfig(end=700.0), sinks=[McapSink(rec)],
               command="benchmarks/report_screenshot.py")
    paths = write_report(rec, out)
    png = out / f"{rec.stem}.screenshot.png"
    screenshot(paths["html"], png)
    st = blank_check(png)
    print(f"html: {paths['html']}")
    print(f"screenshot: {png}")
    print(f"size {st['width']}x{st['height']}, non-white {st['nonwhite']:.3f}, "
          f"coloured {st['coloured']:.4f}")
    ok = st["width"] == 1400 and st["nonwhite"] > 0.02 and st["coloured"] > 0.001
    print("looks rendered" if ok else "looks BLANK")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
