"""Constant-velocity Kalman filter, batched over tracks (GEWC paper, eqs. 8-14).

State (x, y, vx, vy) in pixels and pixels per frame; measurement (x, y).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CVModel:
    """Φ (eq. 8 with dt), H (eq. 9), Q = q·I4 and R = r·I2 as in the paper."""

    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray

    @classmethod
    def make(cls, q: float = 0.2, r: float = 0.4, dt: float = 1.0) -> "CVModel":
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        H = np.eye(2, 4)
        return cls(F, H, q * np.eye(4), r * np.eye(2))


def predict(x: np.ndarray, P: np.ndarray, m: CVModel) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 10-11: x⁻ = Φx, P⁻ = ΦPΦᵀ + Q for stacked states x (N, 4), P (N, 4, 4)."""
    return x @ m.F.T, m.F @ P @ m.F.T + m.Q


def innovation_covariance(P: np.ndarray, m: CVModel) -> np.ndarray:
    """S = HP⁻Hᵀ + R, shape (N, 2, 2)."""
    return m.H @ P @ m.H.T + m.R


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, m: CVModel
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eqs. 12-14: gain, state and covariance update; returns (x, P, innovation (N, 2))."""
    S = innovation_covariance(P, m)
    K = P @ m.H.T @ np.linalg.inv(S)
    nu = z - x @ m.H.T
    x_new = x + np.einsum("nij,nj->ni", K, nu)
    P_new = (np.eye(4) - K @ m.H) @ P
    return x_new, P_new, nu


def initial_covariance(r: float, velocity_std: float) -> np.ndarray:
    """P₀ for a track born from one measurement: position variance r, velocity variance v²."""
    return np.diag([r, r, velocity_std**2, velocity_std**2])
