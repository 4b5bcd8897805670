"""Open3D as a test reference, or a skip where its wheel cannot load.

Open3D's Linux wheel links ``libusb-1.0`` (for its RealSense support), which a bare machine may
lack; ``libusb-package`` ships the library, and loading it first with global symbols lets
Open3D's extension resolve it.
"""

from __future__ import annotations

import ctypes

import pytest


def open3d():
    try:
        import libusb_package
        path = libusb_package.get_library_path()
        if path is not None:
            ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    except (ImportError, OSError):
        pass
    return pytest.importorskip("open3d")


def cloud(points):
    o3d = open3d()
    import numpy as np
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
