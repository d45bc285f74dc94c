"""PC2 point caches (the format Blender's Mesh Cache modifier reads)."""
from __future__ import annotations

import struct

import numpy as np
from numpy.typing import ArrayLike

from .result import ShapeSpaceError

__all__ = ["write_pc2", "read_pc2"]

_HEADER = struct.Struct("<12siiffi")


def write_pc2(path: str, frames: ArrayLike, start_frame: float = 1.0, sample_rate: float = 1.0) -> None:
    """Write positions (samples, p, 3) as a PC2 file (little-endian float32)."""
    data = np.asarray(frames, dtype=np.float64)
    if data.ndim != 3 or data.shape[2] != 3:
        raise ShapeSpaceError(f"frames must have shape (samples, p, 3), got {data.shape}", "shape")
    if not np.isfinite(data).all():
        raise ShapeSpaceError("point cache positions contain NaN or infinite values", "non_finite")
    with open(path, "wb") as fh:
        fh.write(_HEADER.pack(b"POINTCACHE2\0", 1, data.shape[1], float(start_frame), float(sample_rate),
                              data.shape[0]))
        fh.write(data.astype("<f4").tobytes())


def read_pc2(path: str) -> tuple:
    """Read a PC2 file: ``(positions (samples, p, 3), start_frame, sample_rate)``."""
    with open(path, "rb") as fh:
        head = fh.read(_HEADER.size)
        if len(head) != _HEADER.size:
            raise ShapeSpaceError(f"{path} is too short to be a PC2 file", "corrupt_file")
        magic, version, points, start, rate, samples = _HEADER.unpack(head)
        if magic != b"POINTCACHE2\0" or version != 1:
            raise ShapeSpaceError(f"{path} is not a PC2 point cache", "corrupt_file")
        body = np.frombuffer(fh.read(), dtype="<f4")
    if body.size != points * samples * 3:
        raise ShapeSpaceError(f"{path} holds {body.size} floats, expected {points * samples * 3}", "corrupt_file")
    return body.reshape(samples, points, 3).astype(np.float64), start, rate
