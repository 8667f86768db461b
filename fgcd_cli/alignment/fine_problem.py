"""Residuals and Jacobians of the fine alignment at one blur level (rACR Eqs. 9, 10, 16-18).

``E_p`` (Eq. 10) compares the intensities of each selected reference point in
the current keyframes that see it, against their per-point mean (for the squared
loss ``sum_{u,v} (I_u - I_v)^2 = 2K sum_u (I_u - I_mean)^2``); ``E_g`` (Eq. 9)
splits each current point's offset from its matched reference point into the
part along the reference normal and the tangential part, each with its own
robust scale. Both terms are Huber-weighted (IRLS) and normalised by their
robust scales and residual counts, so ``alpha`` weighs dimensionless mean costs
(docs/alignment.md, "Fine-grained alignment").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from scipy import sparse

from fgcd_cli.alignment.photometric import KeyframeImage, project_with_jacobian, sample
from fgcd_cli.alignment.sparse_icp import gram
from fgcd_core import lm
from fgcd_core.camera import PinholeCamera
from fgcd_core.sim3 import Sim3

__all__ = ["Block", "PhotometricObservations", "GeometricMatches", "FineProblem", "huber_weights"]

_HUBER_K = 1.345
"""Huber threshold in units of the robust residual scale (95 % efficiency under Gaussian noise)."""


class Block(StrEnum):
    """Parameters a Jacobian is taken with respect to."""

    KEYFRAMES = "keyframes"
    """The current keyframe poses, 6 per keyframe (Eq. 16)."""
    SIMILARITY = "similarity"
    """The similarity ``T_cur_ref`` (R, t, log-scale; Eqs. 17-18)."""


def huber_weights(r: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """IRLS weights and Huber costs of residuals ``r`` scaled by ``sigma``."""
    a = np.abs(r) / sigma
    return lm.huber_weights(a, _HUBER_K), lm.huber_rho(a, _HUBER_K)


@dataclass(frozen=True, kw_only=True)
class PhotometricObservations:
    """Selected reference points and the current keyframes that see them.

    Attributes
    ----------
    camera : PinholeCamera
        Undistorted intrinsics of the keyframes.
    images : list of KeyframeImage
        Keyframe images blurred for this level.
    ref_pts : (M, 3) ndarray
        Selected reference points, reference frame (metres).
    pt, kf : (n_obs,) int ndarray
        Point index and keyframe index of each observation.
    n_kf : int
        Number of keyframes.
    """

    camera: PinholeCamera
    images: list[KeyframeImage]
    ref_pts: np.ndarray
    pt: np.ndarray
    kf: np.ndarray
    n_kf: int
    by_kf: list[np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "by_kf", [np.flatnonzero(self.kf == u) for u in range(self.n_kf)])

    def residuals(self, S: Sim3, poses: list[np.ndarray], *, block: Block | None):
        """Residuals (n_obs,), validity (n_obs,) and, with ``block``, the Jacobian (n_obs, P) of ``E_p``.

        ``S`` is ``T_cur_ref``; ``poses`` the keyframes' ``T_cur_cam``. An observation is
        valid when in front of the camera, inside the image and one of at least two valid
        observations of its point.
        """
        n_obs = len(self.pt)
        q = S.apply(self.ref_pts)[self.pt]  # current map frame
        intensity = np.zeros(n_obs)
        ok = np.zeros(n_obs, dtype=bool)
        dIdX = np.zeros((n_obs, 3))
        X = np.zeros((n_obs, 3))
        for u, idx in enumerate(self.by_kf):
            if len(idx) == 0:
                continue
            R_u, t_u = poses[u][:3, :3], poses[u][:3, 3]
            Xu = (q[idx] - t_u) @ R_u
            uv, J, front = project_with_jacobian(self.camera, Xu)
            vals, inside = sample(self.images[u], np.nan_to_num(uv))
            intensity[idx] = vals[:, 0]
            ok[idx] = front & inside
            dIdX[idx] = np.einsum("ni,nij->nj", vals[:, 1:3], J)
            X[idx] = Xu
        cnt = np.bincount(self.pt, weights=ok.astype(float), minlength=len(self.ref_pts))
        ok &= cnt[self.pt] >= 2
        cnt = np.bincount(self.pt, weights=ok.astype(float), minlength=len(self.ref_pts))
        mean = np.bincount(self.pt, weights=intensity * ok, minlength=len(self.ref_pts)) / np.maximum(cnt, 1)
        r = np.where(ok, intensity - mean[self.pt], 0.0)
        if block is None:
            return r, ok, None
        JI = self._intensity_jacobian(block, q, dIdX, X, poses)
        JI[~ok] = 0.0
        w_avg = np.where(ok, 1.0 / np.maximum(cnt[self.pt], 1), 0.0)
        A = sparse.csr_matrix((w_avg, (self.pt, np.arange(n_obs))), shape=(len(self.ref_pts), n_obs))
        J = JI - (A @ JI)[self.pt]
        J[~ok] = 0.0
        return r, ok, J

    def _intensity_jacobian(self, block: Block, q, dIdX, X, poses) -> np.ndarray:
        """Jacobian (n_obs, P) of the sampled intensities (before subtracting the per-point mean)."""
        n_obs = len(self.pt)
        if block == Block.KEYFRAMES:
            # Right perturbation T_u <- T_u exp(delta): dX = -rho + X x phi.
            Jb = np.concatenate([-dIdX, np.cross(dIdX, X)], axis=1)
            cols = 6 * self.n_kf
            return sparse.csr_matrix(
                (Jb.ravel(), ((6 * self.kf)[:, None] + np.arange(6)).ravel(), np.arange(0, 6 * n_obs + 1, 6)),
                shape=(n_obs, cols),
            ).toarray()
        # Left perturbation S <- exp(xi) S: dq = rho + phi x q + lambda q; dX = R_u^T dq.
        a = np.zeros((n_obs, 3))
        for u, idx in enumerate(self.by_kf):
            a[idx] = dIdX[idx] @ poses[u][:3, :3].T
        return np.concatenate([a, np.cross(q, a), np.sum(a * q, axis=1, keepdims=True)], axis=1)

    def rms(self, S: Sim3, poses: list[np.ndarray]) -> float:
        """RMS of the valid photometric residuals (grey levels), NaN when none is valid."""
        r, ok, _ = self.residuals(S, poses, block=None)
        return float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float("nan")


@dataclass(frozen=True, kw_only=True)
class GeometricMatches:
    """Current points matched to reference points for ``E_g``, with the robust scales of its two parts.

    Attributes
    ----------
    x : (G, 3) ndarray
        Current points (map frame).
    q, n : (G, 3) ndarray
        Matched reference points and their unit normals (reference frame).
    sigma_g, sigma_t : float
        Robust scales (m) of the normal and the tangential offsets.
    """

    x: np.ndarray
    q: np.ndarray
    n: np.ndarray
    sigma_g: float
    sigma_t: float

    def residuals(self, S: Sim3, *, jac: bool):
        """Residuals of the current points against their matched reference points.

        Returns ``(r_n, r_t, J_n, J_t)``: ``r_n`` (G,) the offset along the
        reference normal (point-to-plane), ``r_t`` (G, 3) the offset within the
        tangent plane. The paper's ``E_g`` (Eq. 9) is point-to-point, i.e. both
        parts with one weight; point-to-plane alone cannot tell the scale from a
        shift along the normal on a nearly flat object, while the normal part is
        far less noisy than the tangential one. So both are kept, each with its
        own robust scale (an anisotropic, GICP-like point-to-point;
        docs/alignment.md, "Fine-grained alignment").
        """
        Sq = S.apply(self.q)
        n_c = self.n @ S.R.T
        d = self.x - Sq
        r_n = np.sum(n_c * d, axis=1)
        r_t = d - n_c * r_n[:, None]
        if not jac:
            return r_n, r_t, None, None
        J_n = np.concatenate([-n_c, -np.cross(Sq, n_c), -np.sum(n_c * Sq, axis=1, keepdims=True)], axis=1)
        # d(Sq)/dxi for the left perturbation S <- exp(xi) S: [I, -[Sq]x, Sq]; d = x - Sq.
        G = len(Sq)
        J_d = np.zeros((G, 3, 7))
        J_d[:, :, 0:3] = -np.eye(3)
        skew = np.zeros((G, 3, 3))
        skew[:, 0, 1], skew[:, 0, 2] = -Sq[:, 2], Sq[:, 1]
        skew[:, 1, 0], skew[:, 1, 2] = Sq[:, 2], -Sq[:, 0]
        skew[:, 2, 0], skew[:, 2, 1] = -Sq[:, 1], Sq[:, 0]
        J_d[:, :, 3:6] = skew
        J_d[:, :, 6] = -Sq
        P_t = np.eye(3)[None] - n_c[:, :, None] * n_c[:, None, :]
        J_t = np.einsum("gij,gjk->gik", P_t, J_d)
        return r_n, r_t, J_n, J_t


class FineProblem:
    """``alpha * E_g + (1 - alpha) * E_p`` at one blur level, with its normal equations.

    Parameters
    ----------
    obs : PhotometricObservations
    geo : GeometricMatches or None
        Without it only ``E_p`` constrains the similarity.
    alpha : float
        Weight of the geometric term.
    sigma_p : float
        Robust scale of the photometric residuals (grey levels).
    """

    def __init__(
        self, obs: PhotometricObservations, geo: GeometricMatches | None, *, alpha: float, sigma_p: float
    ) -> None:
        self.obs = obs
        self.geo = geo
        self.alpha = alpha
        self.sigma_p = sigma_p
        self.n_p = max(1, len(obs.pt))
        self.n_g = max(1, 0 if geo is None else len(geo.x))

    def cost(self, S: Sim3, poses: list[np.ndarray], *, block: Block | None, with_geometry: bool):
        """Total normalised robust cost; with ``block`` also the weighted normal equations ``(H, b)``."""
        r, ok, J = self.obs.residuals(S, poses, block=block)
        w, c = huber_weights(r, self.sigma_p)
        w = np.where(ok, w, 0.0)
        total = (1 - self.alpha) * float(np.sum(c[ok])) / self.n_p if with_geometry else float(np.sum(c[ok])) / self.n_p
        H = b = None
        if J is not None:
            scale_p = ((1 - self.alpha) if with_geometry else 1.0) / (self.n_p * self.sigma_p**2)
            Jw = J * (w * scale_p)[:, None]
            H = gram(Jw, J)
            b = -(r @ Jw)
        if with_geometry and self.geo is not None:
            geo_total, H, b = self._add_geometry(S, total, H, b, jac=J is not None)
            total = geo_total
        return total, H, b

    def _add_geometry(self, S: Sim3, total: float, H, b, *, jac: bool):
        """Add ``alpha * E_g`` to the cost and (with ``jac``) to the normal equations."""
        geo = self.geo
        rn, rt, Jn, Jt = geo.residuals(S, jac=jac)
        wn, cn = huber_weights(rn, geo.sigma_g)
        rt = rt.reshape(-1)
        wt, ct = huber_weights(rt, geo.sigma_t)
        total += self.alpha * (float(np.sum(cn)) + float(np.sum(ct))) / self.n_g
        if Jn is not None:
            scale_n = self.alpha / (self.n_g * geo.sigma_g**2)
            Jnw = Jn * (wn * scale_n)[:, None]
            Jt = Jt.reshape(-1, 7)
            scale_t = self.alpha / (self.n_g * geo.sigma_t**2)
            Jtw = Jt * (wt * scale_t)[:, None]
            H = H + gram(Jnw, Jn) + gram(Jtw, Jt)
            b = b - rn @ Jnw - rt @ Jtw
        return total, H, b
