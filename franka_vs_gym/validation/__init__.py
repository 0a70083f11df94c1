"""Model-vs-measurement workbench: measurement logs, compare, diagnose (which effect is missing), fit, report."""

from franka_vs_gym.validation.logs import MeasurementLog, load_log, save_log

__all__ = ["MeasurementLog", "load_log", "save_log"]
