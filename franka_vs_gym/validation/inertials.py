"""Physically consistent link inertial parameters: the log-Cholesky parametrisation of a rigid body's pseudo-inertia.

A body's 10 inertial parameters (pinocchio order ``[m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz]``,
inertia about the body frame's origin) are physically consistent (a non-negative mass density can produce them)
exactly when the 4x4 **pseudo-inertia**

    J = [[Sigma, h], [h^T, m]],   Sigma = tr(I)/2 * 1 - I,   h = m c

is positive semi-definite (Wensing, Kim and Slotine, "Linear Matrix Inequalities for Physically Consistent Inertial
Parameter Identification: A Statistical Perspective on the Mass Distribution", IEEE RA-L 3(1), 2018); positive
definite is the strict version (positive mass, inertia about the centre of mass positive definite, principal
moments satisfying the triangle inequality strictly). The **log-Cholesky** parametrisation (Rucker and Wensing,
"Smooth Parameterization of Rigid-Body Inertia", IEEE RA-L 7(2), 2022) writes ``J = U U^T`` with

    U = exp(alpha) [[exp(d1), s12, s13, t1], [0, exp(d2), s23, t2], [0, 0, exp(d3), t3], [0, 0, 0, 1]]

so that every real 10-vector ``theta = (alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3)`` gives a positive-definite
J, and every positive-definite J has exactly one theta. An unconstrained least-squares fit over theta is therefore
a physically consistent identification (no LMI solver needed).

:func:`consistent_links` fits the 7 links of the arm this way to a change of the arm's **base parameters** (the 43
combinations joint torques reveal, as identified by Gaz et al. 2019) weighted by how strongly the log's data
determine each combination, regularised towards the published link values so that the directions the data do not
determine (70 standard parameters, 43 base ones) stay at the published values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_IU = np.array([0, 1, 2, 0, 1, 0])  # (row, col) of s12, s23, s13 and the t column are handled explicitly


def pseudo_inertia(pi: np.ndarray) -> np.ndarray:
    """(..., 4, 4) pseudo-inertia of pinocchio dynamic parameters ``pi`` (..., 10)."""
    pi = np.asarray(pi, dtype=float)
    m, h = pi[..., 0], pi[..., 1:4]
    xx, xy, yy, xz, yz, zz = (pi[..., k] for k in range(4, 10))
    inertia = np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)
    tr = np.trace(inertia, axis1=-2, axis2=-1)
    J = np.zeros(pi.shape[:-1] + (4, 4))
    J[..., :3, :3] = 0.5 * tr[..., None, None] * np.eye(3) - inertia
    J[..., :3, 3] = h
    J[..., 3, :3] = h
    J[..., 3, 3] = m
    return J


def params_of(J: np.ndarray) -> np.ndarray:
    """Pinocchio dynamic parameters (..., 10) of pseudo-inertias ``J`` (..., 4, 4)."""
    S = J[..., :3, :3]
    inertia = np.trace(S, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - S
    return np.stack([J[..., 3, 3], J[..., 0, 3], J[..., 1, 3], J[..., 2, 3], inertia[..., 0, 0], inertia[..., 0, 1],
                     inertia[..., 1, 1], inertia[..., 0, 2], inertia[..., 1, 2], inertia[..., 2, 2]], -1)


def params_from_theta(theta: np.ndarray) -> np.ndarray:
    """Log-Cholesky parameters (..., 10) -> pinocchio dynamic parameters (..., 10), always physically consistent."""
    theta = np.clip(np.asarray(theta, dtype=float), -40.0, 40.0)  # trial steps of a solver stay finite
    a = np.exp(theta[..., 0])
    U = np.zeros(theta.shape[:-1] + (4, 4))
    U[..., 0, 0], U[..., 1, 1], U[..., 2, 2] = (np.exp(theta[..., k]) for k in (1, 2, 3))
    U[..., 0, 1], U[..., 1, 2], U[..., 0, 2] = theta[..., 4], theta[..., 5], theta[..., 6]
    U[..., 0, 3], U[..., 1, 3], U[..., 2, 3] = theta[..., 7], theta[..., 8], theta[..., 9]
    U[..., 3, 3] = 1.0
    U = U * a[..., None, None]
    return params_of(U @ np.swapaxes(U, -1, -2))


def theta_from_params(pi: np.ndarray) -> np.ndarray:
    """Pinocchio dynamic parameters (10,) of a physically consistent body (positive-definite pseudo-inertia) -> its
    log-Cholesky parameters (10,). Raises ValueError when the pseudo-inertia is not positive definite."""
    J = pseudo_inertia(pi)
    E = np.eye(4)[::-1]
    try:
        L = np.linalg.cholesky(E @ J @ E)
    except np.linalg.LinAlgError:
        raise ValueError("pseudo-inertia not positive definite: the body is not physically consistent") from None
    U = E @ L @ E  # upper triangular, U U^T = J
    a = U[3, 3]
    V = U / a
    return np.array([np.log(a), np.log(V[0, 0]), np.log(V[1, 1]), np.log(V[2, 2]), V[0, 1], V[1, 2], V[0, 2],
                     V[0, 3], V[1, 3], V[2, 3]])


def prior_scale(pi0: np.ndarray) -> np.ndarray:
    """(7, 10) prior standard deviations of the standard parameters around the published values: 25% of the mass,
    3 cm of centre-of-mass shift times the mass, and 25% of the largest moment of inertia about the frame origin (plus
    a floor of 1e-3 kg m^2), the spread between CAD and identified values in Gaz et al. 2019."""
    pi0 = np.atleast_2d(pi0)
    m = np.abs(pi0[:, 0])
    inertia = np.abs(pi0[:, [4, 6, 9]]).max(axis=1)
    s = np.empty_like(pi0)
    s[:, 0] = 0.25 * m
    s[:, 1:4] = (0.03 * m)[:, None]
    s[:, 4:] = (0.25 * inertia + 1e-3)[:, None]
    return s


WALL = 30.0  # weight of the consistency-margin wall (per unit of log-diagonal beyond the limit)


@dataclass
class ConsistentFit:
    """Result of :func:`consistent_links`: ``links`` (7, 10) consistent parameters, ``dbeta`` (r,) the base-parameter
    change they produce, ``cost`` the data misfit (in the weighting of ``G``) and ``prior`` the prior term."""

    links: np.ndarray
    dbeta: np.ndarray
    cost: float
    prior: float
    nfev: int
    theta: np.ndarray


def consistent_links(K: np.ndarray, G: np.ndarray, dbeta: np.ndarray, pi0: np.ndarray, weight: float,
                     x0: np.ndarray | None = None) -> ConsistentFit:
    """Physically consistent link parameters whose base parameters come closest to ``pi0``'s plus ``dbeta``.

    Minimises ``weight * (K (pi - pi0) - dbeta)^T G (K (pi - pi0) - dbeta) + sum(((pi - pi0) / prior_scale)^2)``, plus
    a wall keeping each pseudo-inertia's Cholesky diagonal within e^-3 of the published links' smallest (so every
    fitted link stays strictly inside the consistent set), over the log-Cholesky parameters of the 7 links
    (``scipy.optimize.least_squares``, Levenberg-Marquardt, Jacobian from the per-link 10x10 blocks). ``K`` (r, 70)
    maps standard to base parameters, ``G`` (r, r) is positive semi-definite (the data's normal matrix in base
    coordinates), ``pi0`` (7, 10) the published (physically consistent) links, ``x0`` an optional warm start (70,).
    """
    from scipy.optimize import least_squares

    pi0 = np.asarray(pi0, dtype=float)
    scale = prior_scale(pi0)
    w, V = np.linalg.eigh(0.5 * (G + G.T))
    C = (V * np.sqrt(np.clip(w, 0.0, None))).T * np.sqrt(weight)  # C^T C = weight G
    th0 = np.array([theta_from_params(p) for p in pi0]) if x0 is None else np.asarray(x0, float).reshape(7, 10)
    CK = C @ K
    # a soft wall keeps each pseudo-inertia away from the boundary of consistency (a flat or a line body, which
    # the plant cannot simulate): the diagonal of U may shrink to e^-3 of the published links' smallest, no further
    th_pub = np.array([theta_from_params(p) for p in pi0])
    d_lim = th_pub[:, 1:4].min(axis=1, keepdims=True) - 3.0

    def resid(x):
        th = x.reshape(7, 10)
        pi = params_from_theta(th)
        d = (pi - pi0).ravel()
        wall = WALL * np.maximum(0.0, d_lim - th[:, 1:4]).ravel()
        return np.concatenate([CK @ d - C @ dbeta, d / scale.ravel(), wall])

    eye = np.eye(10) * 1e-6

    def jac(x):
        th = x.reshape(7, 10)
        base = params_from_theta(th)  # (7, 10)
        steps = params_from_theta(th[:, None, :] + eye[None])  # (7, 10 step, 10 param)
        D = (steps - base[:, None, :]) / 1e-6  # d pi_i / d theta_i, (link, theta, param)
        Jpi = np.zeros((70, 70))
        for i in range(7):
            Jpi[i * 10:(i + 1) * 10, i * 10:(i + 1) * 10] = D[i].T
        Jw = np.zeros((21, 70))
        active = (d_lim - th[:, 1:4]) > 0
        for i in range(7):
            for k in range(3):
                if active[i, k]:
                    Jw[3 * i + k, 10 * i + 1 + k] = -WALL
        return np.vstack([CK @ Jpi, Jpi / scale.ravel()[:, None], Jw])

    # tolerances far below what the plausibility test resolves (a fraction of the noise floor)
    sol = least_squares(resid, th0.ravel(), jac=jac, method="lm", x_scale="jac", xtol=1e-7, ftol=1e-7,
                        max_nfev=150)
    pi = params_from_theta(sol.x.reshape(7, 10))
    d = (pi - pi0).ravel()
    r = CK @ d - C @ dbeta
    return ConsistentFit(pi, K @ d, float(r @ r), float(np.sum((d / scale.ravel()) ** 2)), int(sol.nfev), sol.x)


__all__ = ["ConsistentFit", "consistent_links", "params_from_theta", "params_of", "prior_scale", "pseudo_inertia",
           "theta_from_params"]
