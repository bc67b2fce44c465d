"""uavest: UAV attitude and radar-target estimation with EKF, UKF, EnKF, a hybrid
UKF/EnKF filter and a particle filter, side by side.

Layers (data flows one way; each imports only those above it in this list; checked by
``lint-imports``, the contracts in ``pyproject.toml`` ``[tool.importlinter]``):

- ``uavest.errors`` (the error types), ``uavest.seeding`` (the per-stream random
  generators), ``uavest.layouts`` (the Foxglove layouts' data): leaves usable anywhere.
- ``uavest.compiled``: the registry of the optional numba kernels (one self-check
  against their numpy references, one fallback) and the compiled helpers they share.
- ``uavest.geometry``: rotations, quaternions, state spaces (``retract``/``local``), geodesy.
- ``uavest.link``: the MAVLink link beside it (transport: UDP, TCP, serial; MAVLink 2
  signing; framing: the encoder buffer, tlog records; the ``SPEC_*`` parameters in
  which a vehicle states its sensors' datasheet), shared by the live source, the
  MAVLink publisher and the simulator; knows nothing of samples, filters or records.
- ``uavest.core``: the filter core (knows nothing of MAVLink or files).
- ``uavest.models``: transition and measurement models (know nothing of files).
- ``uavest.ingest``, ``uavest.sim``: sources: bytes (tlog, DataFlash, ULog, live links) to
  typed, timestamped samples, and the MAVLink simulator; know nothing of filters.
- ``uavest.engine``, ``uavest.tracking``: the streaming engine (step builders, the one
  predict/update loop, records and the sample types handed to sinks) and the multi-target
  tracker (predictor/associator/initiator/deleter).
- ``uavest.sinks``, ``uavest.eval``: where records go (JSON, tables, recordings) and the
  metrics, pure functions of records and truth.
- ``uavest.scenarios``, ``uavest.presets``: the built-in scenarios and filter presets.
- ``uavest.apps``, ``uavest.experiments``: jobs composed of the above (replay, Monte
  Carlo and radar trials, speed).
- ``uavest.fleet``, ``uavest.report``: batch evaluation over logs and scenarios; the
  HTML report.
- ``uavest.cli``: the thin command line.
"""

__version__ = "0.1.0"
