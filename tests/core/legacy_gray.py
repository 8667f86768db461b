"""Verbatim copies of the grey converters, CLAHE and SIFT matchers fgcd_core.imaging replaces.

Kept only as the reference the equivalence tests compare against (issue #20):
each is the code at commit 56dc4a9, renamed after its old home.
"""

import cv2
import numpy as np


def drivers_cameras_to_gray_float(image):
    img = np.asarray(image)
    if img.dtype == np.uint8:
        scale = 1.0 / 255.0
    elif img.dtype == np.uint16:
        scale = 1.0 / 65535.0
    else:
        scale = 1.0
    img = img.astype(np.float32) * np.float32(scale)
    if img.ndim == 3:
        img = img[:, :, :3] @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


def vse_features_to_gray_u8(image):
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img if img.dtype == np.uint8 else img.astype(np.float32), cv2.COLOR_RGB2GRAY)
    if img.dtype == np.uint8:
        return img
    return np.clip(np.asarray(img, dtype=np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)


def vse_features_to_gray_f32(image):
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img if img.dtype == np.uint8 else img.astype(np.float32), cv2.COLOR_RGB2GRAY)
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    return np.asarray(img, dtype=np.float32)


def calibration_board_to_gray_u8(image):
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., :3].mean(axis=2) if img.dtype != np.uint8 else cv2.cvtColor(img[..., :3], cv2.COLOR_RGB2GRAY)
    if img.dtype != np.uint8:
        img = np.clip(np.asarray(img, dtype=float) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return img


def handeye_ba_gray_u8(image):
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img.astype(np.float32) if img.dtype != np.uint8 else img, cv2.COLOR_RGB2GRAY)
    if img.dtype != np.uint8:
        img = img.astype(np.float32)
        if img.size and float(np.nanmax(img)) <= 1.0 + 1e-6:
            img = img * 255.0
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def changes_images_to_gray(image):
    if image.ndim == 2:
        return image.astype(np.float32)
    return image.mean(axis=2).astype(np.float32)


def changes_tiled_gray(image):
    if image.ndim == 2:
        return image
    if image.shape[2] == 3 and image.dtype == np.float32:
        return (image[:, :, 0] + image[:, :, 1] + image[:, :, 2]) / np.float32(3)
    return image.mean(axis=2).astype(np.float32)


def alignment_photometric_as_float_gray(image):
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    return img.astype(np.float32)


def relocation_local_contrast(gray, *, clip_limit=3.0, tiles=8):
    u8 = np.clip(np.asarray(gray, dtype=np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    clahe = cv2.createCLAHE(clipLimit=float(clip_limit), tileGridSize=(int(tiles), int(tiles)))
    return clahe.apply(u8).astype(np.float32) / 255.0


def registration_to_uint8(gray):
    return np.clip(gray * 255.0 + 0.5, 0, 255).astype(np.uint8)


def registration_match_sift(ref_gray, cur_gray, *, ratio=0.75, max_features=4000):
    sift = cv2.SIFT_create(nfeatures=int(max_features))
    kp_ref, desc_ref = sift.detectAndCompute(registration_to_uint8(ref_gray), None)
    kp_cur, desc_cur = sift.detectAndCompute(registration_to_uint8(cur_gray), None)
    empty = np.zeros((0, 2))
    if desc_ref is None or desc_cur is None or len(kp_ref) < 2 or len(kp_cur) < 2:
        return empty, empty.copy()
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_ref, desc_cur, k=2)
    good = [pair[0] for pair in knn if len(pair) == 2 and pair[0].distance < ratio * pair[1].distance]
    if not good:
        return empty, empty.copy()
    points_ref = np.array([kp_ref[m.queryIdx].pt for m in good], dtype=np.float64)
    points_cur = np.array([kp_cur[m.trainIdx].pt for m in good], dtype=np.float64)
    return points_ref, points_cur


def handeye_ba_stop_features(images, *, n_features=1500):
    sift = cv2.SIFT_create(nfeatures=n_features)
    clahe = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8))
    out = []
    for img in images:
        kp, desc = sift.detectAndCompute(clahe.apply(handeye_ba_gray_u8(img)), None)
        xy = np.array([k.pt for k in kp], dtype=float).reshape(-1, 2)
        out.append((xy, desc if desc is not None else np.zeros((0, 128), np.float32)))
    return out


def handeye_ba_ratio_one_to_one(d_a, d_b, *, ratio):
    """The matching part of handeye_ba._pair_matches (before its 20-match and fundamental-matrix checks)."""
    matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    knn = matcher.knnMatch(np.asarray(d_a, np.float32), np.asarray(d_b, np.float32), k=2)
    good = [(m[0].queryIdx, m[0].trainIdx) for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    idx = np.array(good, dtype=int).reshape(-1, 2)
    if len(idx):
        _, first, counts = np.unique(idx[:, 1], return_index=True, return_counts=True)
        idx = idx[first[counts == 1]]
    return idx


def transforms_look_at(eye, target, up=(0.0, 0.0, 1.0)):
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    up = np.asarray(up, dtype=float)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def synthetic_look_at(eye, target, *, up=(0.0, -1.0, 0.0)):
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = eye
    return T
