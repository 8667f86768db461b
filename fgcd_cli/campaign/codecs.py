"""Encodings of an observation's files: PNG images, ``.npy`` arrays, binary PLY clouds (bytes in, bytes out)."""

from __future__ import annotations

import io

import numpy as np

from fgcd_cli.errors import CampaignError, DataIntegrityError, UserInputError

__all__ = ["decode_png", "encode_npy", "encode_ply", "encode_png"]


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an 8- or 16-bit grayscale/RGB image (float [0,1] becomes 16-bit)."""
    import cv2

    img = np.asarray(image)
    if img.dtype.kind == "f":
        img = np.clip(np.nan_to_num(img), 0.0, 1.0)
        img = (img * 65535.0 + 0.5).astype(np.uint16)
    elif img.dtype == np.bool_:
        img = img.astype(np.uint8) * 255
    elif img.dtype not in (np.uint8, np.uint16):
        raise UserInputError(f"cannot store an image of dtype {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[:, :, ::-1]  # RGB -> BGR for OpenCV
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise CampaignError("PNG encoding failed")
    return buf.tobytes()


def decode_png(data: bytes) -> np.ndarray:
    """Image from PNG bytes, RGB order for colour images, dtype preserved."""
    import cv2

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DataIntegrityError("image file cannot be decoded")
    if img.ndim == 3:
        img = img[:, :, ::-1].copy()
    return img


def encode_npy(array: np.ndarray) -> bytes:
    """``.npy`` bytes of an array (no pickles)."""
    buf = io.BytesIO()
    np.save(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


def encode_ply(points: np.ndarray, colors: np.ndarray | None = None, normals: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY of a point cloud (readable by Open3D, MeshLab, CloudCompare).

    Written with numpy rather than Open3D because Open3D's writer needs a real
    file path and cannot be made atomic; the format is a short header plus a
    packed record array.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    rec = np.empty(len(P), dtype=fields)
    rec["x"], rec["y"], rec["z"] = P[:, 0], P[:, 1], P[:, 2]
    if normals is not None:
        N = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
        rec["nx"], rec["ny"], rec["nz"] = N[:, 0], N[:, 1], N[:, 2]
    if colors is not None:
        C = np.asarray(colors)
        if C.ndim == 1:
            C = np.repeat(C[:, None], 3, axis=1)
        if C.dtype.kind == "f":
            C = np.clip(C * 255.0 + 0.5, 0, 255)
        C = C.astype(np.uint8)
        rec["red"], rec["green"], rec["blue"] = C[:, 0], C[:, 1], C[:, 2]
    type_names = {"<f8": "double", "<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(P)}"]
    header += [f"property {type_names[t]} {n}" for n, t in fields]
    header += ["end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + rec.tobytes()
