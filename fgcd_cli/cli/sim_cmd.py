"""``fgcd sim``: the simulator backend from the command line (scenes, lights, renders, contact sheet)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import typer

from fgcd_cli.cli.output import emit, info
from fgcd_cli.errors import UserInputError

app = typer.Typer(help="Simulated world: list scenes and lightings, render views with ground truth.",
                  no_args_is_help=True)


def _parse_pose(text: str | None) -> np.ndarray:
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


def _check_output(path: Path, what: str) -> None:
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
        raise UserInputError(f"cannot write {what} {path}: {exc.strerror or exc} ({exc.filename or path.parent})") \
            from None
    if not os.access(path.parent, os.W_OK):
        raise UserInputError(f"cannot write {what} {path}: {path.parent} is not writable")


def _write_png(path: Path, img: np.ndarray, what: str = "image") -> None:
    import cv2

    _check_output(path, what)
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
    _check_output(path, "depth")
    try:
        np.save(path, arr)
    except OSError as exc:
        raise UserInputError(f"cannot write depth {path}: {exc.strerror or exc}") from None


@app.command("scenes")
def scenes(as_json: bool = typer.Option(False, "--json", help="Print one JSON object.")) -> None:
    """List the simulated scenes with their descriptions."""
    from fgcd_drivers.sim.scenes import list_scenes, scenes_dir

    items = [{"name": s.name, "description": s.description} for s in list_scenes()]

    def render(console):
        from rich.table import Table

        table = Table(title=f"Simulated scenes ({scenes_dir()})")
        table.add_column("name", style="bold")
        table.add_column("description")
        for it in items:
            table.add_row(it["name"], it["description"])
        console.print(table)

    emit({"scenes": items, "count": len(items)}, as_json=as_json, render=render)


@app.command("lights")
def lights(as_json: bool = typer.Option(False, "--json", help="Print one JSON object.")) -> None:
    """List the lighting presets."""
    from fgcd_drivers.sim.lights import list_lighting_presets

    items = [{"name": n, "description": d} for n, d in list_lighting_presets()]

    def render(console):
        for it in items:
            console.print(f"[bold]{it['name']}[/bold]  {it['description']}")

    emit({"lightings": items}, as_json=as_json, render=render)


@app.command("render")
def render_cmd(
    scene: str = typer.Option(..., "--scene", help="Scene name (fgcd sim scenes)."),
    light: str = typer.Option("front", "--light", help="Lighting preset (fgcd sim lights)."),
    pose: str | None = typer.Option(None, "--pose", help="x,y,z,rx,ry,rz in mm and degrees, camera frame, "
                                                          "relative to the scene's default camera."),
    out: Path = typer.Option(..., "-o", "--out", help="Output image (PNG)."),
    depth: Path | None = typer.Option(None, "--depth", help="Also write z-depth: .npy (metres) or .png (16-bit mm)."),
    mask: Path | None = typer.Option(None, "--mask", help="Also write the change mask (PNG, 255 = change)."),
    changes: int = typer.Option(0, "--changes", help="Inject this many random changes (1-20 mm)."),
    change_seed: int = typer.Option(1, "--change-seed", help="Seed of the changes."),
    seed: int = typer.Option(0, "--seed", help="Scene seed."),
    gray: bool = typer.Option(False, "--gray", help="Write a grayscale image instead of colour."),
    width: int = typer.Option(640, "--width", help="Image width (px); focal length scales with it."),
    height: int = typer.Option(480, "--height", help="Image height (px)."),
    supersample: int = typer.Option(1, "--supersample", help="Anti-aliasing samples per pixel and axis."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Render one view of a scene (and optionally its depth and change mask)."""
    from fgcd_drivers.cameras import CameraIntrinsics
    from fgcd_drivers.sim.changes import random_changes
    from fgcd_drivers.sim.lights import lighting_preset
    from fgcd_drivers.sim.render import Renderer
    from fgcd_drivers.sim.scenes import SceneNotFound, load_scene

    if out.suffix.lower() != ".png":
        raise UserInputError(f"output must be a .png file, got {out}")
    if depth is not None and depth.suffix.lower() not in (".npy", ".png"):
        raise UserInputError(f"--depth must end in .npy or .png, got {depth}")
    if width < 16 or height < 16 or supersample < 1 or changes < 0:
        raise UserInputError("image size must be >= 16 px, supersample >= 1, changes >= 0")
    T_rel = _parse_pose(pose)
    for path, what in ((out, "image"), (depth, "depth"), (mask, "mask")):
        if path is not None:
            _check_output(path, what)
    try:
        lighting = lighting_preset(light)
    except ValueError as exc:
        raise UserInputError(str(exc)) from None
    try:
        sc = load_scene(scene, seed=seed)
    except SceneNotFound as exc:
        raise UserInputError(str(exc)) from None
    f = 600.0 * width / 640.0
    intr = CameraIntrinsics(fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2, width=width, height=height)
    T = sc.default_T_world_cam @ T_rel
    chs = random_changes(sc, n=changes, seed=change_seed) if changes else []
    renderer = Renderer(sc, supersample=supersample)
    t0 = time.perf_counter()
    res = renderer.render(T, intr, lighting, changes=chs, want=("gray",) if gray else ("rgb",))
    ms = (time.perf_counter() - t0) * 1000
    img = res.gray if gray else res.rgb
    _write_png(out, np.round(img * 255).astype(np.uint8))
    written = {"image": str(out)}
    if depth is not None:
        if depth.suffix.lower() == ".npy":
            _save_npy(depth, res.depth)
        else:
            _write_png(depth, np.clip(np.round(res.depth * 1000), 0, 65535).astype(np.uint16), "depth")
        written["depth"] = str(depth)
    if mask is not None:
        _write_png(mask, res.change_mask.astype(np.uint8) * 255, "mask")
        written["mask"] = str(mask)
    data = {
        "scene": scene, "lighting": lighting.name, "T_world_cam": T, "intrinsics": intr.to_dict(),
        "exposure": res.exposure, "render_ms": ms, "changes": [c.to_dict() for c in chs],
        "change_pixels": int(res.change_mask.sum()), "written": written,
    }

    def show(console):
        console.print(f"rendered [bold]{scene}[/bold] under {lighting.name} in {ms:.0f} ms -> {out}")
        for k, v in written.items():
            if k != "image":
                console.print(f"  {k}: {v}")
        if chs:
            console.print(f"  {len(chs)} changes, {int(res.change_mask.sum())} changed pixels")

    emit(data, as_json=as_json, render=show)


@app.command("contact-sheet")
def contact_sheet(
    out: Path = typer.Option(Path("docs/img/scenes_contact_sheet.png"), "-o", "--out", help="Output PNG."),
    lights_: str = typer.Option("front,led:3,night", "--light", help="Comma-separated lighting presets (columns)."),
    width: int = typer.Option(320, "--width", help="Width of each tile (px)."),
    supersample: int = typer.Option(2, "--supersample", help="Anti-aliasing samples per pixel and axis."),
    as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
) -> None:
    """Every scene (rows) under several lightings (columns), labelled, in one PNG."""
    import cv2

    from fgcd_drivers.cameras import CameraIntrinsics
    from fgcd_drivers.sim.render import Renderer
    from fgcd_drivers.sim.scenes import list_scenes, load_scene

    names = [s.name for s in list_scenes()]
    lights_list = [s.strip() for s in lights_.split(",") if s.strip()]
    h = width * 3 // 4
    f = 600.0 * width / 640.0
    intr = CameraIntrinsics(fx=f, fy=f, cx=(width - 1) / 2, cy=(h - 1) / 2, width=width, height=h)
    rows = []
    for name in names:
        if not as_json:
            info(f"rendering {name}…")
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
    _write_png(out, sheet)
    emit({"written": str(out), "scenes": names, "lightings": lights_list, "size": list(sheet.shape[:2])},
         as_json=as_json)
