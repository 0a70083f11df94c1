"""Published parameters of the Franka Emika Robot (FER), the Franka Research 3 (FR3) and the Franka Hand.

This module is the single source of the numbers the project takes from publications and datasheets. They are
assembled into robot descriptions by :mod:`franka_vs_gym.model.description` (``FER``, ``FR3``), from which the MuJoCo
plant (:mod:`franka_vs_gym.assets.mjcf`) and the pinocchio model (``franka_vs_gym.model.FrankaModel``) are both
built; no number below is typed anywhere else, and no other module reads this one.

Sources
-------
- Kinematics: modified (Craig) Denavit-Hartenberg table of the FER as given in Table I of the FrankaSim paper and
  in the Franka Control Interface documentation.
- Joint limits: Franka Control Interface documentation, limits for the FER (position, velocity, acceleration,
  jerk, torque, torque rate; Cartesian translation, rotation and elbow limits).
- Dynamics: C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano, A. De Luca, "Dynamic Identification of the Franka
  Emika Panda Robot With Retrieval of Feasible Parameters Using Penalty-Based Optimization", IEEE RA-L 2019.
  Masses (kg), centres of mass (m, in the link frame) and inertia tensors (kg m^2, about the centre of mass, axes
  of the link frame), and the sigmoid friction model
  ``tau_f = phi1 / (1 + exp(-phi2 (dq + phi3))) - phi1 / (1 + exp(-phi2 phi3))``.
- Franka Hand: 0.73 kg, CoM (-0.01, 0, 0.03) m and inertia diag(0.001, 0.0025, 0.0017) kg m^2 in the hand frame;
  the hand frame is the flange frame rotated by -45 deg about z; the end-effector (TCP) is 0.1034 m along its z.

FR3 (the ``FR3_*`` names below; typed by hand from the published description, nothing is read at run time):

- Kinematics: the FR3's modified DH table is the FER's (Franka Control Interface documentation, "Denavit-Hartenberg
  parameters"; franka_description ``robots/fr3/kinematics.yaml`` gives the same joint origins: z 0.333, y -0.316,
  x 0.0825, x -0.0825 / y 0.384, x 0.088, flange z 0.107).
- Joint limits: franka_description ``robots/fr3/joint_limits.yaml`` (position, velocity, effort; Franka Robotics,
  Apache-2.0) and the Franka Control Interface documentation, "Limits for Franka Research 3" (acceleration 10
  rad/s^2, jerk 5000 rad/s^3 and torque rate 1000 Nm/s on every joint; Cartesian translation 3.0 m/s, 9.0 m/s^2,
  4500 m/s^3, rotation 2.5 rad/s, 17 rad/s^2, 8500 rad/s^3, elbow 2.62 rad/s, 10 rad/s^2, 5000 rad/s^3). The
  velocity limits are the documentation's "rectangular" ones (the robot lowers them near the position limits).
- Inertials: franka_description ``robots/fr3/inertials.yaml`` (links 1..7; mass kg, centre of mass m in the link
  frame, inertia kg m^2 about the centre of mass with link-frame axes; the link frames are the modified-DH frames).
- Friction: none is published for the FR3. Its users identify it from their own logs with the workbench
  (``franka-vs fit``).

Effective armature (``*_ROTOR_INERTIA``): the reflected inertia of each joint's motor and gear as a torque
controller feels it through the robot's internal torque loop (kg m^2, link side), the inertia between the commanded
torque and the link-side torque sensor. It is not part of the link-side dynamics (the Gaz et al. identification and
libfranka's model describe the links only).

- FR3: MuJoCo Menagerie's ``franka_fr3/fr3.xml`` since 2025-04-25 (pull request 168, "armature, damping, friction
  parameters, identified in torque control", contributed for Franka Robotics): 0.195 kg m^2 on joints 1-4 and
  0.074 kg m^2 on joints 5-7. An identification on one robot, one value per drive size; no error bars are given.
- FER: nothing identified is published. Its drives have the FR3's sizes and torque limits (87 Nm on joints 1-4,
  12 Nm on 5-7), so the FR3's values are used; treat them as known to within a factor of about 2 (Menagerie's
  ``franka_emika_panda`` model carries a uniform 0.1 kg m^2, a modelling choice rather than an identification).
  ``franka-vs fit`` / the workbench's ``armature`` effect identify the value of a given robot from a log with
  ``tau_J_d`` (see :class:`franka_vs_gym.validation.effects.Armature`).

Conventions: SI units; joint index 0..6 in code; link ``i`` (1..7 in prose) is ``LINKS[i-1]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

N_JOINTS = 7

# --- Modified DH table (Craig): frame i is reached from frame i-1 by RotX(alpha_{i-1}) TransX(a_{i-1})
# RotZ(theta_i) TransZ(d_i). One row per joint 1..7, then the flange (fixed, theta = 0).
DH_A = (0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088)
DH_D = (0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0)
DH_ALPHA = (0.0, -math.pi / 2, math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2, math.pi / 2)
FLANGE_D = 0.107

# --- Joint limits (datasheet).
Q_MIN = (-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973)
Q_MAX = (2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973)
DQ_MAX = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)
DDQ_MAX = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)
TAU_MAX = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
DDDQ_MAX = (7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0)  # jerk, rad/s^3
DTAU_MAX = (1000.0,) * 7  # torque rate limit, Nm/s
# Cartesian limits of the end effector (translation v, a, jerk; rotation w, alpha, jerk) and of the elbow (v, a, jerk),
# Franka Control Interface documentation, limits for the FER.
CARTESIAN_LIMITS = (1.7, 13.0, 6500.0, 2.5, 25.0, 12500.0, 2.175, 10.0, 5000.0)

# Neutral pose used by the Franka examples and the FrankaSim experiments (rad).
Q_NEUTRAL = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)


@dataclass(frozen=True)
class LinkInertial:
    """Inertial parameters of one rigid body.

    mass in kg; com (3,) in m in the body frame; inertia (6,) = (ixx, ixy, ixz, iyy, iyz, izz) in kg m^2 about the
    centre of mass, axes of the body frame.
    """

    mass: float
    com: tuple[float, float, float]
    inertia: tuple[float, float, float, float, float, float]

    def inertia_matrix(self) -> np.ndarray:
        ixx, ixy, ixz, iyy, iyz, izz = self.inertia
        return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


# --- Gaz et al. 2019 identified link inertials (links 1..7).
LINKS = (
    LinkInertial(4.970684, (3.875e-03, 2.081e-03, -4.762e-02),
                 (7.0337e-01, -1.39e-04, 6.772e-03, 7.0661e-01, 1.9169e-02, 9.117e-03)),
    LinkInertial(0.646926, (-3.141e-03, -2.872e-02, 3.495e-03),
                 (7.962e-03, -3.925e-03, 1.0254e-02, 2.811e-02, 7.04e-04, 2.5995e-02)),
    LinkInertial(3.228604, (2.7518e-02, 3.9252e-02, -6.6502e-02),
                 (3.7242e-02, -4.761e-03, -1.1396e-02, 3.6155e-02, -1.2805e-02, 1.083e-02)),
    LinkInertial(3.587895, (-5.317e-02, 1.04419e-01, 2.7454e-02),
                 (2.5853e-02, 7.796e-03, -1.332e-03, 1.9552e-02, 8.641e-03, 2.8323e-02)),
    LinkInertial(1.225946, (-1.1953e-02, 4.1065e-02, -3.8437e-02),
                 (3.5549e-02, -2.117e-03, -4.037e-03, 2.9474e-02, 2.29e-04, 8.627e-03)),
    LinkInertial(1.666555, (6.0149e-02, -1.4117e-02, -1.0517e-02),
                 (1.964e-03, 1.09e-04, -1.158e-03, 4.354e-03, 3.41e-04, 5.433e-03)),
    LinkInertial(7.35522e-01, (1.0517e-02, -4.252e-03, 6.1597e-02),
                 (1.2516e-02, -4.28e-04, -1.196e-03, 1.0027e-02, -7.41e-04, 4.815e-03)),
)

# --- Gaz et al. 2019 sigmoid friction (per joint).
FRICTION_PHI1 = (0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489)
FRICTION_PHI2 = (5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336)
FRICTION_PHI3 = (0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526)

# --- Franka Research 3 (see the module docstring for the sources). Kinematics: the DH_* rows above.
FR3_Q_MIN = (-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159)
FR3_Q_MAX = (2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159)
FR3_DQ_MAX = (2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26)
FR3_DDQ_MAX = (10.0,) * 7
FR3_DDDQ_MAX = (5000.0,) * 7
FR3_TAU_MAX = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
FR3_DTAU_MAX = (1000.0,) * 7
# Effective armature (reflected motor and gear inertia as the torque controller feels it), kg m^2, joints 1..7.
FR3_ROTOR_INERTIA = (0.195, 0.195, 0.195, 0.195, 0.074, 0.074, 0.074)  # Menagerie fr3.xml (PR 168)
FER_ROTOR_INERTIA = FR3_ROTOR_INERTIA  # none published for the FER: the FR3's drives (see the module docstring)
FR3_CARTESIAN_LIMITS = (3.0, 9.0, 4500.0, 2.5, 17.0, 8500.0, 2.62, 10.0, 5000.0)
FR3_LINKS = (
    LinkInertial(2.9274653454, (0.0000004128, -0.0181251324, -0.0386035970),
                 (0.023927316485107913, 1.3317903455714081e-05, -0.00011404774918616684, 0.0224821613275756,
                  -0.0019950320628240115, 0.006350098258530016)),
    LinkInertial(2.9355370338, (0.0031828864, -0.0743221644, 0.0088146084),
                 (0.041938946257609425, 0.00020257331521090626, 0.004077784227179924, 0.02514514885014724,
                  -0.0042252158006570156, 0.06170214472888839)),
    LinkInertial(2.2449013699, (0.0407015686, -0.0048200565, -0.0289730823),
                 (0.02410142547240885, 0.002404694559042109, -0.002856269270114313, 0.01974053266708178,
                  -0.002104212683891874, 0.019044494482244823)),
    LinkInertial(2.6155955791, (-0.0459100965, 0.0630492960, -0.0085187868),
                 (0.03452998321913202, 0.01322552265982813, 0.01015142998484113, 0.028881621933049058,
                  -0.0009762833870704552, 0.04125471171146641)),
    LinkInertial(2.3271207594, (-0.0016039605, 0.0292536262, -0.0972965990),
                 (0.051610278463662895, -0.005715173387783472, -0.0035673167625872135, 0.04787729713371481,
                  0.010673985108535986, 0.016423625579357254)),
    LinkInertial(1.8170376524, (0.0597131221, -0.0410294666, -0.0101692726),
                 (0.005412333594383447, 0.006193456360285834, 0.0014219289306117652, 0.014058329545509979,
                  -0.0013140753741120031, 0.016080817924212554)),
    LinkInertial(0.6271432862, (0.0045225817, 0.0086261921, -0.0161633251),
                 (0.00021092389150104718, -2.433299114461931e-05, 4.564480393778983e-05, 0.00017718568002411474,
                  8.744070223226438e-05, 5.993190599659971e-05)),
)

# --- Franka Hand.
HAND = LinkInertial(0.73, (-0.01, 0.0, 0.03), (0.001, 0.0, 0.0, 0.0025, 0.0, 0.0017))
HAND_YAW = -math.pi / 4  # hand frame = flange frame rotated about z
HAND_TCP_Z = 0.1034  # end effector along the hand z axis (m)
HAND_FINGER_Z = 0.0584  # finger joint origin along the hand z axis (m)
HAND_FINGER_OPENING = 0.04  # maximum opening of each finger (m)

# --- Default wrist camera and AprilTag (ViSP Franka tutorials use an 8 cm tag).
TAG_SIZE = 0.08
GRAVITY = (0.0, 0.0, -9.81)


def as_array(values: tuple[float, ...]) -> np.ndarray:
    """A fresh float64 array of a parameter tuple."""
    return np.array(values, dtype=np.float64)


def dh_placement(i: int) -> np.ndarray:
    """4x4 pose of frame i+1 in frame i at theta = 0, for joint index i in 0..6 (modified DH)."""
    return mdh(DH_A[i], DH_D[i], DH_ALPHA[i], 0.0)


def flange_placement() -> np.ndarray:
    """4x4 pose of the flange in the frame of link 7."""
    return mdh(0.0, FLANGE_D, 0.0, 0.0)


def hand_placement() -> np.ndarray:
    """4x4 pose of the hand frame in the flange frame."""
    return mdh(0.0, 0.0, 0.0, HAND_YAW)


def hand_flMe() -> np.ndarray:
    """4x4 pose of the Franka Hand TCP (the end effector) in the flange frame."""
    return hand_placement() @ mdh(0.0, HAND_TCP_Z, 0.0, 0.0)


def mdh(a: float, d: float, alpha: float, theta: float) -> np.ndarray:
    """4x4 modified (Craig) DH transform RotX(alpha) TransX(a) RotZ(theta) TransZ(d)."""
    ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
    return np.array([
        [ct, -st, 0.0, a],
        [st * ca, ct * ca, -sa, -d * sa],
        [st * sa, ct * sa, ca, d * ca],
        [0.0, 0.0, 0.0, 1.0],
    ])
