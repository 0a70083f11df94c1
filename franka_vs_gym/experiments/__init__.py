"""Experiments and demos run from the ``franka-vs`` command (each writes its outputs under runs/)."""
