"""Use case: the simulator backend on its own (``fgcd sim scenes | lights | render | contact-sheet``).

The scenes and lighting presets it knows, one view of a scene rendered with its
ground truth (depth, change mask) and written as files, and the contact sheet of
every scene under several lightings. Every output path is checked, in one line,
before minutes of rendering.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.errors import UserInputError

__all__ = [
    "RenderOutcome",
    "RenderRequest",
    "check_output",
    "contact_sheet",
    "lightings",
    "parse_pose",
    "render_view",
    "scenes",
    "write_png",
]


def scenes() -> tuple[list[dict], Path]:
    """``([{"name", "description"}, ...], the folder they are read from)`` of every simulated scene."""
    from fgcd_drivers.sim.scenes import list_scenes, scenes_dir

    return [{"name": s.name, "description": s.description} for s in list_scenes()], scenes_dir()


def lightings() -> list[dict]:
    """``[{"name", "description"}, ...]`` of every lighting preset."""
    from fgcd_drivers.sim.lights import list_lighting_presets

    return [{"name": n, "description": d} for n, d in list_lighting_presets()]


def parse_pose(text: str | None) -> np.ndarray:
    """``x,y,z,rx,ry,rz`` (mm, deg; camera frame, relative to the scene's default camera) -> 4x4."""
    T = np.eye(4)
    if not text:
        return T
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise UserInputError(f"--pose must be six numbers x,y,z,rx,ry,rz (mm, deg), got {text!r}") from None
    if len(vals) != 6:
        raise UserInputError(f"--pose must be six numbers x,y,z,rx,ry,rz (mm, deg), got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise UserInputError(f"--pose must be six finite numbers x,y,z,rx,ry,rz (mm, deg), got {text!r}")
    from scipy.spatial.transform import Rotation

    T[:3, :3] = Rotation.from_euler("xyz", vals[3:], degrees=True).as_matrix()
    T[:3, 3] = np.asarray(vals[:3]) / 1000.0
    return T


def check_output(path: Path, what: str) -> None:
    """Fail early, in one line, if ``path`` cannot be written (before minutes of rendering)."""
    if path.is_dir():
        raise UserInputError(f"cannot write {what} {path}: it is a directory")
    for anc in path.parents:
        if anc.exists():
            if not anc.is_dir():
                raise UserInputError(f"cannot write {what} {path}: {anc} is not a directory")
            break
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserInputError(
            f"cannot write {what} {path}: {exc.strerror or exc} ({exc.filename or path.parent})"
        ) from None
    if not os.access(path.parent, os.W_OK):
        raise UserInputError(f"cannot write {what} {path}: {path.parent} is not writable")


def write_png(path: Path, img: np.ndarray, what: str = "image") -> None:
    """Write ``img`` (RGB, gray or 16-bit) to ``path`` through a temporary file (UserInputError when it cannot)."""
    import cv2

    check_output(path, what)
    tmp = path.with_name(path.name + ".tmp.png")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    try:
        ok = cv2.imwrite(str(tmp), img)
        if ok:
            tmp.replace(path)
    except (OSError, cv2.error) as exc:
        tmp.unlink(missing_ok=True)
        raise UserInputError(f"cannot write {what} {path}: {exc}") from None
    if not ok:
        raise UserInputError(f"cannot write {what} {path}")


def _save_npy(path: Path, arr: np.ndarray) -> None:
    check_output(path, "depth")
    try:
        np.save(path, arr)
    except OSError as exc:
        raise UserInputError(f"cannot write depth {path}: {exc.strerror or exc}") from None


def _intrinsics(width: int, height: int):
    from fgcd_core.camera import CameraIntrinsics

    f = 600.0 * width / 640.0
    return CameraIntrinsics(fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2, width=width, height=height)


@dataclass(frozen=True, kw_only=True)
class RenderRequest:
    """One view of a scene to render (``fgcd sim render``).

    Attributes
    ----------
    scene, light : str
        Scene name and lighting preset.
    pose : str or None
        ``x,y,z,rx,ry,rz`` in mm and degrees, camera frame, relative to the scene's default camera.
    out : Path
        The image (PNG).
    depth, mask : Path or None
        Also the z-depth (``.npy`` metres or ``.png`` 16-bit mm) and the change mask (PNG, 255 = change).
    changes, change_seed, seed : int
        Random changes to inject (1-20 mm), their seed, the scene's seed.
    gray : bool
        A grayscale image instead of colour.
    width, height, supersample : int
        Image size (the focal length scales with the width) and anti-aliasing samples per pixel and axis.
    """

    scene: str
    out: Path
    light: str = "front"
    pose: str | None = None
    depth: Path | None = None
    mask: Path | None = None
    changes: int = 0
    change_seed: int = 1
    seed: int = 0
    gray: bool = False
    width: int = 640
    height: int = 480
    supersample: int = 1


@dataclass(frozen=True, kw_only=True)
class RenderOutcome:
    """What :func:`render_view` rendered and wrote.

    Attributes
    ----------
    record : dict
        ``fgcd sim render --json``'s object.
    lighting : str
        The lighting's name.
    render_ms : float
    written : dict
        ``{"image": path, "depth": path, "mask": path}`` of the files written.
    changes : int
        Changes injected.
    change_pixels : int
        Changed pixels in the view.
    """

    record: dict
    lighting: str
    render_ms: float
    written: dict
    changes: int
    change_pixels: int


def _check_render(r: RenderRequest) -> np.ndarray:
    if r.out.suffix.lower() != ".png":
        raise UserInputError(f"output must be a .png file, got {r.out}")
    if r.depth is not None and r.depth.suffix.lower() not in (".npy", ".png"):
        raise UserInputError(f"--depth must end in .npy or .png, got {r.depth}")
    if r.width < 16 or r.height < 16 or r.supersample < 1 or r.changes < 0:
        raise UserInputError("image size must be >= 16 px, supersample >= 1, changes >= 0")
    T_rel = parse_pose(r.pose)
    for path, what in ((r.out, "image"), (r.depth, "depth"), (r.mask, "mask")):
        if path is not None:
            check_output(path, what)
    return T_rel


def render_view(request: RenderRequest) -> RenderOutcome:
    """Render one view of a scene (and optionally its depth and change mask) and write it.

    Every option is checked (UserInputError, exit 2) before anything is rendered or written.
    """
    from fgcd_drivers.sim.change_placement import random_changes
    from fgcd_drivers.sim.lights import lighting_preset
    from fgcd_drivers.sim.render import Renderer
    from fgcd_drivers.sim.scenes import SceneNotFound, load_scene

    r = request
    T_rel = _check_render(r)
    try:
        lighting = lighting_preset(r.light)
    except ValueError as exc:
        raise UserInputError(str(exc)) from None
    try:
        sc = load_scene(r.scene, seed=r.seed)
    except SceneNotFound as exc:
        raise UserInputError(str(exc)) from None
    intr = _intrinsics(r.width, r.height)
    T = sc.default_T_world_cam @ T_rel
    chs = random_changes(sc, n=r.changes, seed=r.change_seed) if r.changes else []
    renderer = Renderer(sc, supersample=r.supersample)
    t0 = time.perf_counter()
    res = renderer.render(T, intr, lighting, changes=chs, want=("gray",) if r.gray else ("rgb",))
    ms = (time.perf_counter() - t0) * 1000
    img = res.gray if r.gray else res.rgb
    write_png(r.out, np.round(img * 255).astype(np.uint8))
    written = {"image": str(r.out)}
    if r.depth is not None:
        if r.depth.suffix.lower() == ".npy":
            _save_npy(r.depth, res.depth)
        else:
            write_png(r.depth, np.clip(np.round(res.depth * 1000), 0, 65535).astype(np.uint16), "depth")
        written["depth"] = str(r.depth)
    if r.mask is not None:
        write_png(r.mask, res.change_mask.astype(np.uint8) * 255, "mask")
        written["mask"] = str(r.mask)
    record = {
        "scene": r.scene,
        "lighting": lighting.name,
        "T_world_cam": T,
        "intrinsics": intr.to_dict(),
        "exposure": res.exposure,
        "render_ms": ms,
        "changes": [c.to_dict() for c in chs],
        "change_pixels": int(res.change_mask.sum()),
        "written": written,
    }
    return RenderOutcome(
        record=record,
        lighting=lighting.name,
        render_ms=ms,
        written=written,
        changes=len(chs),
        change_pixels=int(res.change_mask.sum()),
    )


def contact_sheet(
    out: Path, *, lights: str, width: int, supersample: int, say: Callable[[str], None] | None = None
) -> dict:
    """Every scene (rows) under several lightings (columns), labelled, in one PNG; ``fgcd sim contact-sheet``'s record.

    Parameters
    ----------
    out : Path
        The PNG to write.
    lights : str
        Comma-separated lighting presets (the columns).
    width : int
        Width of each tile (px; 4:3).
    supersample : int
        Anti-aliasing samples per pixel and axis.
    say : callable(str), optional
        One line per scene rendered.
    """
    import cv2

    from fgcd_drivers.sim.render import Renderer
    from fgcd_drivers.sim.scenes import list_scenes, load_scene

    names = [s.name for s in list_scenes()]
    lights_list = [s.strip() for s in lights.split(",") if s.strip()]
    intr = _intrinsics(width, width * 3 // 4)
    rows = []
    for name in names:
        if say is not None:
            say(f"rendering {name}…")
        sc = load_scene(name)
        r = Renderer(sc, supersample=supersample)
        tiles = []
        for lt in lights_list:
            img = (r.render(sc.default_T_world_cam, intr, lt, want=("rgb",)).rgb * 255).round().astype(np.uint8)
            img = np.ascontiguousarray(img)
            cv2.putText(img, f"{name} / {lt}", (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(img, f"{name} / {lt}", (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
            tiles.append(img)
        rows.append(np.concatenate(tiles, axis=1))
    sheet = np.concatenate(rows, axis=0)
    write_png(out, sheet)
    return {"written": str(out), "scenes": names, "lightings": lights_list, "size": list(sheet.shape[:2])}
