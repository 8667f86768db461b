"""Fine-grained changes injected between two observations, with ground-truth masks.

A change sits on the object's surface at ``position`` with surface normal
``normal``; its footprint is a small raster (``footprint``) in the tangent plane,
generated from its seed. The renderer applies it where camera rays hit the
surface within the footprint:

* ``crack``: a narrow branching groove (0.3-1 mm wide, 1-2 mm deep), darker;
* ``flaking``: a shallow irregular depression (0.3-1 mm) exposing a lighter layer;
* ``stain``: albedo only: a dark brown stain (water, biological) is an absorbing
  layer that filters the stone's own albedo (multiplies it by a brown
  transmission, so it darkens a dark stone as much, relatively, as a light one),
  a whitish efflorescence is a scattering salt crust that covers it (the albedo
  moves towards white);
* ``missing``: a lost fragment, a deeper depression (2-8 mm) with fresh, lighter stone;
* ``pit``: a small roughly round bowl (pitting), relief only: depth
  ``min(2, 0.3 * size_mm)`` mm by default, albedo unchanged;
* ``lifted``: a lifted paint flake, relief only: an irregular plate raised out of
  the surface and tilted, its free edge up to ``min(2, 0.3 * size_mm)`` mm high
  by default (a negative ``depth_mm``), albedo unchanged.

``KINDS`` (the first four) is the default of :func:`fgcd_drivers.sim.change_placement.random_changes`, kept so that
a seed draws the same changes as before the relief-only kinds existed;
``ALL_KINDS`` adds ``pit`` and ``lifted``. ``CHANGE_CATEGORY`` says which cue a
kind changes: ``relief`` (shading only, seen under a directional light),
``colour`` (albedo only, seen under every light) or ``both``.

Geometry changes are rendered as a displacement in shading space (depth moved
along the ray, normal tilted by the relief's slope, a cavity darkening term), not
as mesh edits: at 1-20 mm that is what a camera 0.4-2 m away sees, and it keeps
the ray-casting scene fixed. The relief of a change is ``depth_m * relief()``
(inward; negative is outward); for the first four kinds ``relief()`` is the
footprint itself. Shadow rays of crack, flaking and missing start at the
displaced point (the mesh around a deep depression shadows it); those of pit and
lifted start at the mesh surface (their shallow relief casts no modelled shadow,
attached shadows come from the tilted normal). Ambient light lost in a cavity is
``0.5 * min(H / 2 mm, 1) * F`` (H the summed depth, F the footprint); a pit
scales it so that at its bottom it is the cosine-weighted share of the sky its
rim hides, ``d^2 / (d^2 + R^2)`` (depth d, radius R). The ground-truth mask is
the set of pixels whose surface point lies where the footprint is >= 0.5; the
change ids say which change (the one with the strongest footprint) it is.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["ChangeSpec", "ChangeEffect", "KINDS", "ALL_KINDS", "CHANGE_CATEGORY", "evaluate_changes"]

KINDS = ("crack", "flaking", "stain", "missing")
ALL_KINDS = KINDS + ("pit", "lifted")
CHANGE_CATEGORY = {
    "crack": "both",
    "flaking": "both",
    "missing": "both",
    "stain": "colour",
    "pit": "relief",
    "lifted": "relief",
}
_RELIEF_ONLY = ("pit", "lifted")
_RASTER = 96


def _tangent_basis(normal: np.ndarray, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    n = normal / np.linalg.norm(normal)
    ref = np.asarray(up, float)
    if abs(n @ ref) > 0.9:
        ref = np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, n)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return e1, e2


@dataclass(frozen=True, kw_only=True)
class ChangeSpec:
    """One change.

    Attributes
    ----------
    kind : one of ``ALL_KINDS``.
    position : (3,) world point on the surface, metres.
    normal : (3,) outward surface normal there.
    size_mm : float
        Extent of the footprint (1-20 mm typical).
    seed : int
        Shape of the footprint.
    depth_mm : float or None
        Depth of the depression, mm (None: a default for the kind; stains have
        none). A pit's is > 0; a lifted flake's is < 0, the height of its free
        edge above the surface.
    """

    kind: str
    position: tuple[float, float, float]
    normal: tuple[float, float, float]
    size_mm: float
    seed: int = 0
    depth_mm: float | None = None
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in ALL_KINDS:
            raise ValueError(f"unknown change kind {self.kind!r}; known: {', '.join(ALL_KINDS)}")
        if self.depth_mm is not None and self.kind == "lifted" and not self.depth_mm < 0:
            raise ValueError(f"a lifted flake rises out of the surface: depth_mm must be < 0, got {self.depth_mm}")
        if self.depth_mm is not None and self.kind == "pit" and not self.depth_mm > 0:
            raise ValueError(f"a pit's depth_mm must be > 0, got {self.depth_mm}")
        if self.depth_mm is not None and self.kind not in _RELIEF_ONLY and not self.depth_mm >= 0:
            raise ValueError(f"depth_mm of a {self.kind} must be >= 0, got {self.depth_mm}")
        if not (0.1 <= self.size_mm <= 500):
            raise ValueError(f"change size {self.size_mm} mm out of range")
        n = np.asarray(self.normal, float)
        object.__setattr__(self, "normal", tuple(n / np.linalg.norm(n)))
        object.__setattr__(self, "position", tuple(float(x) for x in self.position))

    # -- derived quantities
    @property
    def category(self) -> str:
        """Cue the change alters: ``relief``, ``colour`` or ``both`` (see ``CHANGE_CATEGORY``)."""
        return CHANGE_CATEGORY[self.kind]

    @property
    def depth_m(self) -> float:
        """Depth of the relief at ``relief() == 1``, metres (inward; negative is outward)."""
        if self.kind == "stain":
            return 0.0
        if self.depth_mm is not None:
            return self.depth_mm / 1000.0
        relief_mm = min(2.0, 0.3 * self.size_mm)
        default = {
            "crack": 1.5,
            "flaking": 0.6,
            "missing": min(6.0, 0.4 * self.size_mm),
            "pit": relief_mm,
            "lifted": -relief_mm,
        }[self.kind]
        return default / 1000.0

    @property
    def occlusion_scale(self) -> float:
        """Factor on the cavity rule ``0.5 * min(H / 2 mm, 1) * F`` (1 but for pit and lifted).

        A pit's makes the lost ambient light at its bottom ``d^2 / (d^2 + R^2)``,
        the cosine-weighted share of the sky hidden by a rim of radius R seen from
        depth d; a lifted flake is no cavity (0).
        """
        if self.kind == "lifted":
            return 0.0
        if self.kind != "pit":
            return 1.0
        d, r = self.depth_m, 0.5 * self.size_mm / 1000.0
        return (d * d / (d * d + r * r)) / (0.5 * min(d / 0.002, 1.0))

    @property
    def shadows_from_surface(self) -> bool:
        """True if shadow rays start at the mesh surface rather than at the displaced point."""
        return self.kind in _RELIEF_ONLY

    @property
    def half_extent_m(self) -> float:
        """Half side of the footprint raster, metres (a margin around ``size_mm``)."""
        return 0.6 * self.size_mm / 1000.0

    @property
    def target_albedo(self) -> tuple[np.ndarray, float]:
        """(RGB the albedo moves towards, how far at footprint 1); see :attr:`albedo_filters`."""
        if self.kind in _RELIEF_ONLY:
            return np.zeros(3), 0.0
        if self.kind == "crack":
            return np.array([0.08, 0.07, 0.06]), 0.75
        if self.kind == "flaking":
            return np.array([0.86, 0.82, 0.74]), 0.55
        if self.kind == "missing":
            return np.array([0.80, 0.74, 0.64]), 0.45
        if self.albedo_filters:
            # the transmission of a brown absorbing layer: at the centre (weight 0.5) a stone of albedo 0.6
            # becomes the brown (0.41, 0.38, 0.35), a darker stone darker in proportion
            return np.array([0.37, 0.28, 0.17]), 0.5
        return np.array([0.95, 0.95, 0.93]), 0.5  # efflorescence

    @property
    def albedo_filters(self) -> bool:
        """True when the change multiplies the albedo (``target_albedo`` is a transmission), False when it
        covers it (the albedo moves towards ``target_albedo``). Only a dark stain filters (module docstring)."""
        return self.kind == "stain" and bool(np.random.default_rng(self.seed + 7).random() < 0.5)

    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """Tangent axes (e1, e2) of the footprint raster."""
        return _tangent_basis(np.asarray(self.normal))

    def footprint(self) -> np.ndarray:
        """(96, 96) float32 in [0, 1] over ``[-half_extent, half_extent]^2`` (rows = e2, cols = e1)."""
        if "F" not in self._cache:
            if self.kind in _RELIEF_ONLY:
                self._cache["F"], self._cache["R"] = _make_relief_footprint(self.kind, self.size_mm, self.seed)
            else:
                self._cache["F"] = _make_footprint(self.kind, self.size_mm, self.seed)
        return self._cache["F"]

    def relief(self) -> np.ndarray:
        """(96, 96) float32 in [0, 1]: the relief is ``depth_m * relief()`` (the footprint but for lifted)."""
        F = self.footprint()
        return self._cache.get("R", F)

    def footprint_at(self, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
        """Footprint value at tangent coordinates (metres), bilinear, 0 outside."""
        F = self.footprint()
        return _sample(F, self._to_raster(a_m), self._to_raster(b_m))

    def relief_at(self, a_m: np.ndarray, b_m: np.ndarray) -> np.ndarray:
        """``relief()`` at tangent coordinates (metres), bilinear, 0 outside."""
        return _sample(self.relief(), self._to_raster(a_m), self._to_raster(b_m))

    def _to_raster(self, x_m: np.ndarray) -> np.ndarray:
        h = self.half_extent_m
        return ((np.asarray(x_m) + h) / (2 * h) * _RASTER - 0.5).astype(np.float32)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "position": list(self.position),
            "normal": list(self.normal),
            "size_mm": self.size_mm,
            "seed": self.seed,
            "depth_mm": self.depth_m * 1000.0,
        }


def _sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a small float image at float pixel coords, 0 outside."""
    n = x.size
    if n == 0:
        return np.zeros(0, np.float32)
    cols = 1024
    rows = (n + cols - 1) // cols
    mx = np.full(rows * cols, -10.0, np.float32)
    my = np.full(rows * cols, -10.0, np.float32)
    mx[:n] = x.ravel()
    my[:n] = y.ravel()
    out = cv2.remap(
        img,
        mx.reshape(rows, cols),
        my.reshape(rows, cols),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    return out.ravel()[:n]


def _make_footprint(kind: str, size_mm: float, seed: int) -> np.ndarray:
    """Procedural footprint raster; the change spans about ``size_mm`` across."""
    rng = np.random.default_rng(seed)
    n = _RASTER
    px_per_mm = n / (1.2 * size_mm)
    c = (n - 1) / 2.0
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    r_px = 0.5 * size_mm * px_per_mm
    if kind == "crack":
        # a random walk across the footprint with one branch, drawn anti-aliased
        width_mm = float(np.clip(0.04 * size_mm, 0.3, 1.0))
        canvas = np.zeros((n * 4, n * 4), np.uint8)
        s = 4.0

        def walk(start, heading, length_px, steps):
            pts = [np.array(start, float)]
            h = heading
            for _ in range(steps):
                h += rng.normal(0, 0.35)
                pts.append(pts[-1] + length_px / steps * np.array([np.cos(h), np.sin(h)]))
            return np.array(pts)

        heading = rng.uniform(0, 2 * np.pi)
        main = walk((c, c), heading, r_px, 12)
        other = walk((c, c), heading + np.pi, r_px, 12)
        line = np.concatenate([other[::-1], main[1:]])
        thick = max(1, int(round(width_mm * px_per_mm * s)))
        cv2.polylines(canvas, [np.round(line * s).astype(np.int32)], False, 255, thick, cv2.LINE_AA)
        k = rng.integers(4, len(line) - 4)
        branch = walk(line[k], heading + rng.choice([-1, 1]) * rng.uniform(0.6, 1.2), 0.5 * r_px, 6)
        cv2.polylines(canvas, [np.round(branch * s).astype(np.int32)], False, 255, max(1, thick // 2 + 1), cv2.LINE_AA)
        F = cv2.resize(canvas.astype(np.float32) / 255.0, (n, n), interpolation=cv2.INTER_AREA)
    else:
        # an irregular blob: a disc with a noisy radius
        ang = np.arctan2(yy - c, xx - c)
        rad = np.hypot(yy - c, xx - c)
        k = np.arange(1, 6)
        amp = rng.normal(0, 0.12, 5) / k
        ph = rng.uniform(0, 2 * np.pi, 5)
        wobble = 1.0 + (amp[:, None, None] * np.cos(k[:, None, None] * ang[None] + ph[:, None, None])).sum(0)
        edge = r_px * wobble
        softness = {"flaking": 0.8, "stain": 0.22 * r_px + 0.8, "missing": 0.8}[kind]
        F = np.clip(0.5 + (edge - rad) / (2 * softness), 0, 1).astype(np.float32)
        if kind == "stain":
            F = F * np.clip(1.0 + 0.15 * rng.standard_normal((n, n)).astype(np.float32), 0.6, 1.2)
            F = np.clip(cv2.GaussianBlur(F, (5, 5), 1.0), 0, 1)
    # nothing at the raster border, so the footprint is exactly zero outside it
    F[[0, -1], :] = 0
    F[:, [0, -1]] = 0
    return F.astype(np.float32)


def _make_relief_footprint(kind: str, size_mm: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Footprint and relief rasters (96, 96) float32 of a ``pit`` or ``lifted`` change.

    A pit is a paraboloid bowl under a slightly wobbly rim of diameter ``size_mm``
    (footprint = relief = ``1 - (r / rim)^2``). A lifted flake is an irregular blob
    (footprint) whose relief rises linearly across it along a random direction,
    from 0.25 at the hinged side to 1 at the free edge.
    """
    rng = np.random.default_rng(seed)
    n = _RASTER
    c = (n - 1) / 2.0
    r_px = 0.5 * n / 1.2
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    ang = np.arctan2(yy - c, xx - c)
    rad = np.hypot(yy - c, xx - c)
    k = np.arange(1, 6)
    amp = rng.normal(0, 0.05 if kind == "pit" else 0.12, 5) / k
    ph = rng.uniform(0, 2 * np.pi, 5)
    edge = r_px * (1.0 + (amp[:, None, None] * np.cos(k[:, None, None] * ang[None] + ph[:, None, None])).sum(0))
    if kind == "pit":
        F = np.clip(1.0 - (rad / edge) ** 2, 0, 1).astype(np.float32)
        R = F
    else:
        F = np.clip(0.5 + (edge - rad) / 1.6, 0, 1).astype(np.float32)
        heading = rng.uniform(0, 2 * np.pi)
        u = ((xx - c) * np.cos(heading) + (yy - c) * np.sin(heading)) / r_px
        R = F * np.clip(0.25 + 0.375 * (u + 1.0), 0, 1).astype(np.float32)
    for a in (F, R):
        a[[0, -1], :] = 0
        a[:, [0, -1]] = 0
    return F, R


@dataclass(kw_only=True)
class ChangeEffect:
    """What the changes do to a set of surface samples (only affected samples listed).

    Attributes
    ----------
    index : (K,) int indices into the samples given to :func:`evaluate_changes`.
    footprint : (K,) float in [0, 1], the strongest footprint there.
    change_index : (K,) int, index (into the ``changes`` given) of the change with that footprint.
    height_m : (K,) depth of the relief, metres (inward; negative is outward).
    slope : (K, 3) gradient of the relief depth in world coordinates (tilts the normal).
    albedo_target : (K, 3) RGB the albedo moves towards (a transmission where ``albedo_filters``).
    albedo_weight : (K,) how far (0..1).
    albedo_filters : (K,) bool, the albedo moves towards ``albedo * albedo_target`` (an absorbing layer).
    occlusion : (K,) share of the ambient light the cavity hides (0..1).
    shadow_height_m : (K,) the part of ``height_m`` that also moves the start of shadow rays.
    """

    index: np.ndarray
    footprint: np.ndarray
    change_index: np.ndarray
    height_m: np.ndarray
    slope: np.ndarray
    albedo_target: np.ndarray
    albedo_weight: np.ndarray
    occlusion: np.ndarray
    shadow_height_m: np.ndarray
    albedo_filters: np.ndarray

    @classmethod
    def empty(cls) -> ChangeEffect:
        return cls(
            index=np.zeros(0, np.int64),
            footprint=np.zeros(0, np.float32),
            change_index=np.zeros(0, np.int64),
            height_m=np.zeros(0),
            slope=np.zeros((0, 3)),
            albedo_target=np.zeros((0, 3)),
            albedo_weight=np.zeros(0),
            occlusion=np.zeros(0),
            shadow_height_m=np.zeros(0),
            albedo_filters=np.zeros(0, bool),
        )

    def albedo_of(self, albedo: np.ndarray) -> np.ndarray:
        """The changed albedo (K, 3) of the affected samples' albedo ``albedo`` (K, 3)."""
        target = np.where(self.albedo_filters[:, None], albedo * self.albedo_target, self.albedo_target)
        w = self.albedo_weight[:, None]
        return (albedo * (1 - w) + w * target).astype(albedo.dtype)


def evaluate_changes(changes, points: np.ndarray, normals: np.ndarray) -> ChangeEffect:
    """Footprint, relief and albedo change of every change at surface samples.

    Parameters
    ----------
    changes : sequence of ChangeSpec
    points : (N, 3) world points hit by camera rays, metres.
    normals : (N, 3) their unit surface normals.

    Returns
    -------
    ChangeEffect for the samples inside at least one footprint (overlaps: the
    strongest footprint, the first on ties, gives the albedo, the change index and
    the occlusion scale; reliefs add).
    """
    if not changes or len(points) == 0:
        return ChangeEffect.empty()
    acc: dict[int, list] = {}
    for i, ch in enumerate(changes):
        if id(ch) in acc:
            continue
        local = _change_at(ch, points, normals)
        if local is not None:
            acc[id(ch)] = [i, *local]
    if not acc:
        return ChangeEffect.empty()
    n = len(points)
    Fsum = np.zeros(n, np.float32)
    H = np.zeros(n)
    Hs = np.zeros(n)
    S = np.zeros((n, 3))
    T = np.zeros((n, 3))
    W = np.zeros(n)
    filters = np.zeros(n, bool)
    ids = np.zeros(n, np.int64)
    occ_scale = np.ones(n)
    for i, idx, F, h, slope, ch in acc.values():
        target, weight = ch.target_albedo
        stronger = F > Fsum[idx]
        T[idx[stronger]] = target
        W[idx[stronger]] = weight * F[stronger]
        filters[idx[stronger]] = ch.albedo_filters
        ids[idx[stronger]] = i
        occ_scale[idx[stronger]] = ch.occlusion_scale
        Fsum[idx] = np.maximum(Fsum[idx], F)
        H[idx] += h
        if not ch.shadows_from_surface:
            Hs[idx] += h
        S[idx] += slope
    sel = np.nonzero(Fsum > 0)[0]
    occlusion = 0.5 * np.clip(H[sel] / 0.002, 0, 1) * Fsum[sel] * occ_scale[sel]
    return ChangeEffect(
        index=sel,
        footprint=Fsum[sel],
        change_index=ids[sel],
        height_m=H[sel],
        slope=S[sel],
        albedo_target=T[sel],
        albedo_weight=W[sel],
        occlusion=occlusion,
        shadow_height_m=Hs[sel],
        albedo_filters=filters[sel],
    )


def _change_at(ch: ChangeSpec, points: np.ndarray, normals: np.ndarray):
    """One change at surface samples: (index, footprint, relief depth, slope, ch) or None.

    ``index`` (M,) into ``points``, ``footprint`` (M,) float32, ``relief depth`` (M,)
    metres along the inward normal, ``slope`` (M, 3) its world gradient.
    """
    c = np.asarray(ch.position)
    nrm = np.asarray(ch.normal)
    h = ch.half_extent_m
    d = points - c
    near = np.einsum("ij,ij->i", d, d) < 2.0 * h * h + 1e-12
    if not near.any():
        return None
    idx = np.nonzero(near)[0]
    dn = d[idx]
    # same surface: close to the tangent plane and facing the same way
    off = dn @ nrm
    ok = (np.abs(off) < max(0.004, 0.5 * h)) & (normals[idx] @ nrm > 0.5)
    idx, dn = idx[ok], dn[ok]
    if len(idx) == 0:
        return None
    e1, e2 = ch.basis()
    a, b = dn @ e1, dn @ e2
    F = ch.footprint_at(a, b)
    hit = F > 1e-4
    if not hit.any():
        return None
    idx, a, b, F = idx[hit], a[hit], b[hit], F[hit]
    depth = ch.depth_m
    relief_is_footprint = ch.relief() is ch.footprint()
    rel = F if relief_is_footprint else ch.relief_at(a, b)
    if depth != 0:
        at = ch.footprint_at if relief_is_footprint else ch.relief_at
        eps = ch.half_extent_m / _RASTER
        Fa = (at(a + eps, b) - at(a - eps, b)) / (2 * eps)
        Fb = (at(a, b + eps) - at(a, b - eps)) / (2 * eps)
        # limit the slope: a real groove wall is steep but the normal tilt saturates
        slope = depth * (Fa[:, None] * e1 + Fb[:, None] * e2)
        sn = np.linalg.norm(slope, axis=1, keepdims=True)
        slope = slope / np.maximum(1.0, sn / 3.0)
    else:
        slope = np.zeros((len(idx), 3))
    return idx, F, depth * rel, slope, ch
