"""The streaming estimation engine: typed, timestamped samples in, one at a time; filter
steps out of a step builder (:mod:`.attitude` for IMU streams; the experiments and the
tracker make theirs); every estimator stepped by :class:`.runner.FilterRunner` or
:class:`.runner.TrackerRunner`; every record (:mod:`.records`) handed to sinks
(:mod:`uavest.sinks`). :func:`.loop.run` is the loop."""

from .loop import run
from .records import RunInfo, ScanRecord, Start, Step, StepRecord, TrackEstimate, Update
from .runner import FilterRunner, TrackerRunner

__all__ = [
    "FilterRunner", "RunInfo", "ScanRecord", "Start", "Step", "StepRecord", "TrackEstimate",
    "TrackerRunner", "Update", "run",
]
