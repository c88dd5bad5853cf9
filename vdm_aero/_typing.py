"""Array aliases and the one axis convention of the library.

Axis convention: snapshot-major. A snapshot matrix is ``(M, N)``: M snapshots (rows, time samples
over all cases) by N surface points (columns). Coefficient arrays are ``(M, 6)`` in the order
``[CX, CY, CZ, Croll, Cpitch, Cyaw]`` (body axes, FRD).
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
from numpy.typing import NDArray

FloatArray: TypeAlias = NDArray[np.floating]
F64Array: TypeAlias = NDArray[np.float64]
IntArray: TypeAlias = NDArray[np.int64]
BoolArray: TypeAlias = NDArray[np.bool_]

COEFF_NAMES: tuple[str, ...] = ("CX", "CY", "CZ", "Croll", "Cpitch", "Cyaw")
