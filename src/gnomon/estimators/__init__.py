"""Attitude estimators: one module per family; see ``registry`` for the names."""
