"""uavest: UAV attitude and radar-target estimation with EKF, UKF, EnKF, a hybrid
UKF/EnKF filter and a particle filter, side by side.

Layers (data flows one way; each imports only those above it in this list):

- ``uavest.geometry``: rotations, quaternions, state spaces (``retract``/``local``).
- ``uavest.core``: the filter core (knows nothing of MAVLink or files).
- ``uavest.models``: transition and measurement models (know nothing of files).
- ``uavest.ingest``: sources: bytes (tlog, DataFlash, ULog, live links) to typed,
  timestamped samples; knows nothing of filters.
- ``uavest.tracking``: the multi-target tracker (predictor/associator/initiator/deleter).
- ``uavest.engine``: the streaming engine: step builders, the one predict/update loop,
  records.
- ``uavest.sinks``, ``uavest.eval``: where records go (JSON, tables, recordings) and the
  metrics, pure functions of records and truth.
- ``uavest.apps``, ``uavest.experiments``: jobs composed of the above (replay, Monte
  Carlo and radar trials, speed); ``uavest.cli``: the thin command line.
"""

__version__ = "0.1.0"
