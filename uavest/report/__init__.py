"""``uavest report``: a recording (MCAP, :mod:`uavest.sinks.mcap`) read back with the
``mcap`` reader -> metrics recomputed from it -> a self-contained HTML page (figures as
base64 PNG, no network needed) and a Markdown summary (figures also as PNG files).

Entry point: :func:`write_report`. Reading: :mod:`uavest.report.read`; metrics and
figures: :mod:`uavest.report.build`."""

from __future__ import annotations

from .build import write_report
from .read import Recording, read_recording

__all__ = ["Recording", "read_recording", "write_report"]
