"""Scripted policies with the stable-baselines3 ``predict`` signature, on the same observations and actions as the
environments: classical visual servoing (IBVS, PBVS) and torque control (computed torque, joint impedance)."""

from baselines.servo import IBVSPolicy, PBVSPolicy
from baselines.torque import ComputedTorquePolicy, JointImpedancePolicy

__all__ = ["ComputedTorquePolicy", "IBVSPolicy", "JointImpedancePolicy", "PBVSPolicy"]
