"""Transition and measurement models (vectorised; know nothing of files or links)."""
