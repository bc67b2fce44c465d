"""The multi-target tracker: ``tracker`` (predictor, associator, initiator, deleter) and
``scenario`` (the radar scenario's truth, detections and models)."""
