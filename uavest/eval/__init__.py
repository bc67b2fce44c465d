"""Evaluation: metrics computed from the pipeline's outputs."""
