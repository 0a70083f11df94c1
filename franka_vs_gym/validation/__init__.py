"""Model-vs-measurement workbench: measurement logs, compare, diagnose (which effect is missing), fit, report.

Typical use::

    from franka_vs_gym.validation import load_log, compare, diagnose, fit_effects
    log = load_log("run.csv")
    print(compare(log).rmse_tau)                  # per-joint torque RMSE of the default model, Nm
    d = diagnose(log)                             # ranking of the candidate effects, verdict
    f = fit_effects(log, d.selected)              # fit, apply to the model and the plant, re-compare
    f.after.save("calibrated.json")               # loads in FrankaModel, FrankaSim, gymnasium.make(model=...)
"""

from franka_vs_gym.validation.bench import bench_compare_diagnose
from franka_vs_gym.validation.compare import CompareResult, baseline_config, compare, replay
from franka_vs_gym.validation.diagnose import diagnose
from franka_vs_gym.validation.effects import LIBRARY, get_effect
from franka_vs_gym.validation.fitting import fit_effects
from franka_vs_gym.validation.loading import load_log
from franka_vs_gym.validation.logs import MeasurementLog, save_log
from franka_vs_gym.validation.results import Diagnosis, FitResult
from franka_vs_gym.validation.signals import CleanSettings, ProcessedLog, clean

__all__ = ["CleanSettings", "CompareResult", "Diagnosis", "FitResult", "LIBRARY", "MeasurementLog", "ProcessedLog",
           "baseline_config", "bench_compare_diagnose", "clean", "compare", "diagnose", "fit_effects", "get_effect",
           "load_log", "replay", "save_log"]
