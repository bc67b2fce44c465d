"""Geometry leaf: rotations and quaternion maths (:mod:`.rotation`) and the state spaces
with their retraction ``retract`` / ``local`` (:mod:`.spaces`). Imports nothing else of
uavest; ingest, models and the filter core all build on it."""
