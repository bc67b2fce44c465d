"""uavest: UAV attitude and radar-target estimation with EKF, UKF, EnKF, a hybrid
UKF/EnKF filter and a particle filter, side by side.

Layers (data flows one way):

- ``uavest.core``: filter core (knows nothing of MAVLink or files).
- ``uavest.models``: transition and measurement models (know nothing of files).
- ``uavest.ingest``: bytes (tlog, DataFlash, ULog, live links) to typed measurements.
- ``uavest.pipeline``: runs filters over a measurement stream.
- ``uavest.bench`` / ``uavest.eval``: Monte Carlo harness and metrics.
"""

__version__ = "0.1.0"
