"""The published parameters, checked against an independent source: the franka_description URDF shipped by the
installed example-robot-data package (Gaz et al. inertials, FER kinematics, Franka Hand)."""

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from franka_vs_gym.assets.mjcf import mesh_dir
from franka_vs_gym.model import params


@pytest.fixture(scope="module")
def urdf():
    path = mesh_dir().parents[1] / "urdf" / "panda.urdf"
    return ET.parse(path).getroot()


def _floats(s):
    return np.array([float(x) for x in s.split()])


def test_link_inertials_match_urdf(urdf):
    links = {lk.get("name"): lk for lk in urdf.iter("link")}
    for i, link in enumerate(params.LINKS):
        inertial = links[f"panda_link{i + 1}"].find("inertial")
        assert float(inertial.find("mass").get("value")) == pytest.approx(link.mass, rel=1e-9)
        np.testing.assert_allclose(_floats(inertial.find("origin").get("xyz")), link.com, atol=1e-9)
        I = inertial.find("inertia")
        urdf_I = [float(I.get(k)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")]
        np.testing.assert_allclose(urdf_I, link.inertia, atol=1e-9)


def test_hand_matches_urdf(urdf):
    hand = {lk.get("name"): lk for lk in urdf.iter("link")}["panda_hand"].find("inertial")
    assert float(hand.find("mass").get("value")) == pytest.approx(params.HAND.mass)
    np.testing.assert_allclose(_floats(hand.find("origin").get("xyz")), params.HAND.com)
    joints = {j.get("name"): j for j in urdf.iter("joint")}
    assert _floats(joints["panda_hand_joint"].find("origin").get("rpy"))[2] == pytest.approx(params.HAND_YAW)
    assert _floats(joints["panda_hand_tcp_joint"].find("origin").get("xyz"))[2] == pytest.approx(params.HAND_TCP_Z)


def test_joint_limits_match_urdf(urdf):
    joints = {j.get("name"): j for j in urdf.iter("joint")}
    for i in range(7):
        lim = joints[f"panda_joint{i + 1}"].find("limit")
        assert float(lim.get("lower")) == pytest.approx(params.Q_MIN[i])
        assert float(lim.get("upper")) == pytest.approx(params.Q_MAX[i])
        assert float(lim.get("velocity")) == pytest.approx(params.DQ_MAX[i])
        assert float(lim.get("effort")) == pytest.approx(params.TAU_MAX[i])


def test_dh_placements_match_urdf_joint_origins(urdf):
    joints = {j.get("name"): j for j in urdf.iter("joint")}
    for i in range(7):
        o = joints[f"panda_joint{i + 1}"].find("origin")
        xyz, rpy = _floats(o.get("xyz")), _floats(o.get("rpy"))
        M = params.dh_placement(i)
        np.testing.assert_allclose(M[:3, 3], xyz, atol=1e-12)
        a = rpy[0]  # only roll is used in the FER's URDF
        Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        np.testing.assert_allclose(M[:3, :3], Rx, atol=1e-12)


def test_inertias_about_com_are_physical():
    """Inertia about the CoM: positive definite and satisfying the triangle inequality (a physical body)."""
    for link in list(params.LINKS) + [params.HAND]:
        ev = np.linalg.eigvalsh(link.inertia_matrix())
        assert ev.min() > 0
        assert ev[0] + ev[1] >= ev[2] - 1e-12


def test_inertias_about_link_origin_would_not_be_physical_for_some_links():
    """The issue's warning: read about the link origin (parallel axis theorem subtracted), links 3, 4 and 6 are not
    positive definite, which is why the tensors are taken about the CoM."""
    bad = []
    for i, link in enumerate(params.LINKS):
        c = np.array(link.com)
        I_c = link.inertia_matrix() - link.mass * (c @ c * np.eye(3) - np.outer(c, c))
        if np.linalg.eigvalsh(I_c).min() <= 0:
            bad.append(i + 1)
    assert {3, 4, 6} <= set(bad)


def test_friction_vanishes_at_rest():
    from franka_vs_gym.model import FrankaModel

    np.testing.assert_allclose(FrankaModel().friction(np.zeros(7)), 0.0, atol=1e-12)
