"""Place the named landmarks on the shared heads from their own shapes and write ``tools/landmarks/<head>.json``.

    .venv/bpy50/bin/python tools/landmarks/find_landmarks.py [HEAD ...]

Each landmark is found by :func:`core.authoring.features.locate_from_shapes` (the rule per landmark:
``core.authoring.features.HOW``, also written into each file's ``notes``), then checked: the mirror distance
of each landmark to the mirror image of its partner (mm at a 30 cm head) is printed and stored in the notes.
The vertex indices are derived data (no mesh data is copied), so the file of a head that may not be vendored
(Ready Player Me) is fine to keep here.
"""
from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import bench_landmarks  # noqa: E402
import package  # noqa: E402


def mirror_errors(verts, tris, landmarks) -> dict:
    """Per landmark, mm (30 cm head) between it and the mirror image of its partner across the skin's mirror plane
    (a midline landmark: twice its distance from the plane)."""
    from shapespace.core.authoring import mm_per_unit, symmetry_plane, triangle_parts
    from shapespace.core.authoring.named import mirror_name
    part, _ = triangle_parts(len(verts), tris)
    normal, offset, _ = symmetry_plane(verts[part == 0])
    mm = mm_per_unit(verts[part == 0])
    out = {}
    for name, v in landmarks.items():
        partner = landmarks.get(mirror_name(name))
        if partner is None:
            continue
        p = verts[partner]
        image = p - 2.0 * (p @ normal - offset) * normal
        out[name] = float(np.linalg.norm(verts[v] - image) * mm)
    return out


def main(tags) -> int:
    package.load()
    from shapespace.core.authoring.features import HOW, locate_from_shapes
    from shapespace.core.authoring.named import head_file_text
    for tag in tags:
        head = bench_landmarks.read_head(tag)
        if head is None:
            continue
        V, T, D, N = head
        landmarks, _ = locate_from_shapes(V, T, D, N)
        mirror = mirror_errors(V, T, landmarks)
        notes = {}
        for name in landmarks:
            base = name[:-2] if name.endswith(("_L", "_R")) else name
            notes[name] = f"{HOW[base]}; mirror {mirror.get(name, 0.0):.2f} mm"
        with open(bench_landmarks.landmark_path(tag), "w", encoding="utf-8") as fh:
            fh.write(head_file_text(landmarks, len(V), notes))
        worst = max(mirror.items(), key=lambda kv: kv[1])
        print(f"{tag}: {len(landmarks)} landmarks, mirror median {np.median(list(mirror.values())):.2f} mm, "
              f"worst {worst[0]} {worst[1]:.2f} mm", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:] or list(bench_landmarks.HEADS)))
