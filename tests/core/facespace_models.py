"""Rigs and brute-force references shared by the core tests of core.facespace."""
import numpy as np

from core.blendshape import BlendshapeModel


def random_model(seed=0, p=30, n=6, wide=False, smooth=False):
    rng = np.random.default_rng(seed)
    neutral = rng.normal(size=(p, 3))
    if smooth:  # displacements vary smoothly over the vertices, like a real face
        centres = rng.uniform(-1.5, 1.5, size=(n, 3))
        fall = np.exp(-((neutral[None] - centres[:, None]) ** 2).sum(axis=2))
        deltas = fall[..., None] * rng.normal(size=(n, 1, 3)) * 0.2
    else:
        deltas = rng.normal(size=(n, p, 3)) * 0.1
    kw = dict(slider_min=np.full(n, -100.0), slider_max=np.full(n, 100.0)) if wide else {}
    return BlendshapeModel(neutral, deltas, [f"key{k}" for k in range(n)], **kw)


def correlated_faces(rng, f=3000, n=6):
    A = rng.normal(size=(n, n))
    return rng.normal(size=(f, n)) @ A + rng.normal(size=n), A.T @ A
