"""The reference cloud, indexed once and reused by every alignment call.

The relocation loop aligns the growing current cloud against the same reference
cloud many times per second; building the KD-tree, the point spacing and the
normals once is what keeps one fast alignment under 100 ms.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["ReferenceIndex", "local_roughness"]


def local_roughness(points: np.ndarray, *, samples: int = 1000, neighbours: int = 50, seed: int = 0) -> float:
    """Median RMS distance of points to the plane through their ``neighbours`` nearest neighbours.

    A noise estimate of a cloud that needs no alignment (it also contains the
    surface's curvature at the neighbourhood scale, small for dense clouds).
    Semi-dense VSE points are locally coherent along image edges, so small
    neighbourhoods (16) underestimate their noise several times over
    (docs/lab/2026-11-25-code-comment-measurements.md, "Alignment"); 50 neighbours see it.
    """
    pts = np.asarray(points, dtype=float)
    if len(pts) <= neighbours:
        return 0.0
    rng = np.random.default_rng(seed)
    sample = pts[rng.choice(len(pts), size=min(samples, len(pts)), replace=False)]
    _, idx = cKDTree(pts).query(sample, k=neighbours, workers=2)
    nb = pts[idx]
    nb = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb) / neighbours
    smallest = np.linalg.eigvalsh(cov)[:, 0]
    return float(np.median(np.sqrt(np.clip(smallest, 0.0, None))))


class ReferenceIndex:
    """Reference point cloud (metric, ``ref`` frame) with a KD-tree and derived statistics.

    Parameters
    ----------
    points : (M, 3) ndarray
        Reference points in metres.
    normals : (M, 3) ndarray, optional
        Unit normals; estimated with Open3D (k nearest neighbours) on first use if omitted.
    intensities : (M,) ndarray, optional
        Grey values in [0, 1] of the reference points (used only to pick textured
        points for the photometric term, never compared with current images).
    normal_neighbours : int
        Neighbours used to estimate normals.
    remove_outliers : bool
        Drop isolated points first: a point is kept if its distance to its
        ``outlier_neighbours``-th neighbour is at most ``outlier_factor`` times the
        25th percentile of that distance. Points a session did not reconstruct
        consistently ("non-repeated" points) are sparse and otherwise attract
        correspondences and spoil the normals.

    Attributes
    ----------
    points, tree, centroid, rms_radius, width, spacing
        ``points`` are the kept points (see ``remove_outliers``); ``kept`` marks them in the input.
        ``rms_radius``: RMS distance to the centroid (m); ``width``: largest
        extent along the principal axes (m); ``spacing``: median nearest-neighbour
        distance (m). ``width`` ignores the outer 1 % of points on each side.
    view : (T_ref_cam (4, 4) ndarray, PinholeCamera), optional
        The camera the cloud was captured for (the reference camera), which
        tells the object's outline from the edge of the view (:attr:`view_rim`).
    """

    def __init__(
        self,
        points: np.ndarray,
        *,
        normals: np.ndarray | None = None,
        intensities: np.ndarray | None = None,
        normal_neighbours: int = 50,
        remove_outliers: bool = True,
        outlier_neighbours: int = 8,
        outlier_factor: float = 3.0,
        view: tuple | None = None,
    ) -> None:
        pts = np.ascontiguousarray(np.asarray(points, dtype=float))
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 10:
            raise ValueError(f"reference points must be (M>=10, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("reference points contain NaN or inf")
        keep = np.ones(len(pts), dtype=bool)
        if remove_outliers and len(pts) > 4 * outlier_neighbours:
            # Density filter: the distance to the k-th neighbour against the dense quarter of the
            # cloud. Open3D's statistical filter (mean + n std) is defeated when stray points are
            # a large population (its mean and std then include them), hence this rule.
            d, _ = cKDTree(pts).query(pts, k=outlier_neighbours + 1, workers=2)
            dk = d[:, -1]
            keep = dk <= outlier_factor * np.percentile(dk, 25)
        self.kept = keep
        """(M_input,) bool: which input points were kept."""
        pts = np.ascontiguousarray(pts[keep])
        self.points = pts
        self.tree = cKDTree(pts, balanced_tree=False, compact_nodes=False)
        self.centroid = pts.mean(axis=0)
        centred = pts - self.centroid
        self.rms_radius = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
        axes = np.linalg.svd(centred[:: max(1, len(pts) // 5000)], full_matrices=False)[2]
        proj = centred @ axes.T
        # Robust extent (1st-99th percentile): stray points must not inflate every threshold.
        lo, hi = np.percentile(proj, [1.0, 99.0], axis=0)
        self.width = float(np.max(hi - lo))
        rng = np.random.default_rng(0)
        sample = pts[rng.choice(len(pts), size=min(len(pts), 2000), replace=False)]
        d, _ = self.tree.query(sample, k=2)
        self.spacing = float(np.median(d[:, 1]))
        self.intensities = None if intensities is None else np.asarray(intensities, dtype=float).reshape(-1)
        if self.intensities is not None:
            if len(self.intensities) != len(keep):
                raise ValueError("reference intensities must have one value per point")
            self.intensities = self.intensities[keep]
        self._normals = None if normals is None else _unit_rows(np.asarray(normals, dtype=float))
        if self._normals is not None:
            if self._normals.shape != (len(keep), 3):
                raise ValueError("reference normals must be (M, 3) like the points")
            self._normals = self._normals[keep]
        self._normal_neighbours = int(normal_neighbours)
        self._contrast: np.ndarray | None = None
        self._roughness: float | None = None
        self._smooth: tuple | None = None
        self._view_rim: np.ndarray | None = None
        self._view = view

    def __len__(self) -> int:
        return len(self.points)

    @property
    def normals(self) -> np.ndarray:
        """(M, 3) unit normals (estimated with Open3D on first access if not given)."""
        if self._normals is None:
            import open3d as o3d

            pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
            pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(self._normal_neighbours))
            self._normals = _unit_rows(np.asarray(pcd.normals))
        return self._normals

    @property
    def roughness(self) -> float:
        """Noise estimate of the reference cloud (m), see :func:`local_roughness`."""
        if self._roughness is None:
            self._roughness = local_roughness(self.points)
        return self._roughness

    @property
    def smooth_radius(self) -> float:
        """Neighbourhood radius of :meth:`smooth_normals` (m)."""
        return max(10.0 * self.roughness, 5.0 * self.spacing, 0.05 * self.width)

    def smooth_normals(self) -> tuple[np.ndarray, np.ndarray, cKDTree]:
        """Normals at a scale well above the noise, for the conditioning check.

        The cloud is voxel-downsampled (voxel = a third of the radius
        ``max(10 x roughness, 5 x spacing, 5 % of the width)``) and normals
        estimated on 30 neighbours there: on a noisy plane, fine-scale normals
        scatter by tens of degrees (docs/lab/2026-11-25-code-comment-measurements.md, "Alignment") and would hide
        the degeneracy.

        Returns
        -------
        points : (K, 3) ndarray, normals : (K, 3) ndarray, tree : cKDTree over ``points``
        """
        if self._smooth is None:
            import open3d as o3d

            radius = self.smooth_radius
            pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points)).voxel_down_sample(radius / 3.0)
            pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(30))
            pts = np.asarray(pcd.points)
            self._smooth = (pts, _unit_rows(np.asarray(pcd.normals)), cKDTree(pts))
        return self._smooth

    @property
    def view_rim(self) -> np.ndarray:
        """(M,) bool: points on the cloud's rim where the rim is the edge of the view.

        A point is on the rim when the centroid of its 24 nearest neighbours
        lies more than 0.3 of the neighbourhood radius away from it (half a
        disc puts it at 0.42, a full disc at 0). A rim is either the object's
        own outline (where the surface ends; another session sees it end at
        the same place) or where the camera stopped seeing a surface that goes
        on, or a limb (the occluding contour of a curved surface, which moves
        with the viewpoint). With ``view=(T_ref_cam, camera)`` given at
        construction, rim points that the reference camera sees inside its
        image (8 % from the border) on a surface facing it (normal within 60
        degrees of the ray) are outline; every other rim point is view rim.
        Without ``view`` every rim point is.
        """
        if self._view_rim is None:
            d, idx = self.tree.query(self.points, k=25, workers=2)
            offset = np.linalg.norm(self.points[idx[:, 1:]].mean(axis=1) - self.points, axis=1)
            rim = offset > 0.3 * d[:, -1]
            if self._view is not None and np.any(rim):
                T_ref_cam, camera = self._view
                T = np.asarray(T_ref_cam, dtype=float)
                uv, in_view = camera.project((self.points[rim] - T[:3, 3]) @ T[:3, :3])
                m = 0.08 * min(camera.width, camera.height)
                inner = (
                    in_view
                    & (uv[:, 0] >= m)
                    & (uv[:, 0] <= camera.width - 1 - m)
                    & (uv[:, 1] >= m)
                    & (uv[:, 1] <= camera.height - 1 - m)
                )
                # An outline faces the camera up to where it ends; a limb (a sphere's or a
                # drum's occluding contour) turns away from it and moves with the viewpoint.
                rays = self.points[rim] - T[:3, 3]
                rays /= np.linalg.norm(rays, axis=1, keepdims=True)
                facing = np.abs(np.sum(rays * self.normals[rim], axis=1)) >= 0.5
                rim[np.flatnonzero(rim)[inner & facing]] = False
            self._view_rim = rim
        return self._view_rim

    @property
    def contrast(self) -> np.ndarray | None:
        """(M,) local intensity standard deviation over 8 neighbours, or None without intensities."""
        if self.intensities is None:
            return None
        if self._contrast is None:
            _, idx = self.tree.query(self.points, k=8, workers=2)
            self._contrast = self.intensities[idx].std(axis=1)
        return self._contrast

    def nearest(self, query: np.ndarray, *, max_distance: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Nearest reference point of each query point.

        Returns
        -------
        distance : (N,) ndarray
            Metres; ``inf`` where nothing lies within ``max_distance``.
        index : (N,) int ndarray
            Index into :attr:`points`; ``len(self)`` where nothing was found.
        """
        # Thread start-up costs more than it saves on small queries.
        workers = 2 if len(query) > 5000 else 1
        return self.tree.query(query, workers=workers, distance_upper_bound=max_distance)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)
