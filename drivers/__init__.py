"""The world: platform drivers, cameras, the simulator and protocol emulators.

Nothing here imports ``fgcd_cli``. Importing this package makes sure Open3D can
find ``libusb-1.0.so.0``: when the system library is missing (a machine where
the Debian package ``libusb-1.0-0`` could not be installed) the copy shipped by
the PyPI package ``libusb-package`` is loaded globally first.
"""

from __future__ import annotations

import ctypes
import ctypes.util


def _ensure_libusb() -> None:
    if ctypes.util.find_library("usb-1.0"):
        return
    try:
        import libusb_package  # type: ignore[import-not-found]

        path = libusb_package.get_library_path()
        if path:
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    except Exception:  # noqa: BLE001 - best effort; open3d's own error is clearer
        pass


_ensure_libusb()
