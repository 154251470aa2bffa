"""Error metrics of an image against a reference: the code `gilab compare` runs.

Images are linear HDR float arrays of shape (height, width, 3), or paths of EXR files.
MSE = mean((x-y)^2); relMSE = mean((x-y)^2 / (y^2 + 0.01)); SMAPE = mean(|x-y| / (|x|+|y|+0.01)),
over all pixels and channels; FLIP is LDR-FLIP (NVIDIA's implementation) after the display
transform (default: ACES at 0 EV, as `gilab compare`).
"""

from __future__ import annotations

import json
import os
from typing import Dict, Union

import numpy as np

from . import _gilab

ImageLike = Union[np.ndarray, str, "os.PathLike[str]"]

__all__ = ["mse", "relmse", "smape", "flip", "compare", "as_image"]


def as_image(image: ImageLike) -> np.ndarray:
    """A float32 (height, width, 3) array: the array itself, or the EXR file read."""
    if isinstance(image, (str, os.PathLike)):
        return _gilab.read_exr(os.fspath(image))
    array = np.ascontiguousarray(image, dtype=np.float32)
    if array.ndim != 3 or array.shape[2] not in (3, 4):
        raise ValueError(f"expected an image of shape (height, width, 3), got {array.shape}")
    return np.ascontiguousarray(array[:, :, :3])


def _three(image: ImageLike, reference: ImageLike):
    return _gilab.error_metrics(as_image(image), as_image(reference))


def mse(image: ImageLike, reference: ImageLike) -> float:
    """Mean squared error of `image` against `reference`."""
    return _three(image, reference)[0]


def relmse(image: ImageLike, reference: ImageLike) -> float:
    """Relative MSE: mean((x-y)^2 / (y^2 + 0.01))."""
    return _three(image, reference)[1]


def smape(image: ImageLike, reference: ImageLike) -> float:
    """Symmetric mean absolute percentage error: mean(|x-y| / (|x|+|y|+0.01))."""
    return _three(image, reference)[2]


def flip(
    image: ImageLike,
    reference: ImageLike,
    operator: str = "aces",
    exposure: float = 0.0,
) -> float:
    """Mean LDR-FLIP after the display transform (`operator`, `exposure` in EV stops)."""
    settings = json.dumps({"operator": operator, "exposure": exposure})
    return _gilab.ldr_flip(as_image(image), as_image(reference), settings)


def compare(image: ImageLike, reference: ImageLike) -> Dict[str, float]:
    """All four numbers `gilab compare A.exr B.exr` prints: mse, relmse, smape, flip."""
    a, b = as_image(image), as_image(reference)
    m, r, s = _gilab.error_metrics(a, b)
    return {"mse": m, "relmse": r, "smape": s, "flip": _gilab.ldr_flip(a, b, None)}
