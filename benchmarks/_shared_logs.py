"""Where the benchmarks find the shared real logs: ``$UAVEST_LOGS`` or
``repo_root/../shared/logs`` (as tests/conftest.py). Imported by the scripts beside it."""

from __future__ import annotations

import os
from pathlib import Path

SHARED_LOGS = (Path(os.environ["UAVEST_LOGS"]) if os.environ.get("UAVEST_LOGS")
               else Path(__file__).resolve().parents[1].parent / "shared" / "logs")
