"""Angles: the one wrap every module uses.

Convention: headings and heading errors are wrapped to :math:`(-\\pi, \\pi]`.
:func:`wrap_angles` is the same for NumPy arrays (reports and figures).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

__all__ = ["wrap_angle", "wrap_angles"]


def wrap_angle(angle: float) -> float:
    """``angle`` (rad) wrapped to :math:`(-\\pi, \\pi]`."""
    wrapped = math.remainder(angle, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped


def wrap_angles(angles: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Element-wise :func:`wrap_angle` of an array (rad), to :math:`(-\\pi, \\pi]`."""
    a = np.asarray(angles, dtype=np.float64)
    wrapped = np.remainder(a + np.pi, 2.0 * np.pi) - np.pi  # [-pi, pi)
    return np.where(wrapped == -np.pi, np.pi, wrapped)
