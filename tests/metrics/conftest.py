"""py-motmetrics 1.4 calls ``np.asfarray``, which NumPy 2 removed (in ``iou_matrix`` and
``norm2squared_matrix``); restore it for the reference computations only."""

import numpy as np

if not hasattr(np, "asfarray"):
    np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)
