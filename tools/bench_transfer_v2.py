"""Transfer v2 benchmark keys (issue #22): every ordered pair of the four shared heads, skin and parts together.

Heads are read whole, as a user rigs them: Face Cap's head with its separate eye and teeth meshes, FBHead,
ICT FaceKit, Ready Player Me's head with its eye and teeth objects (read from ../shared/data, never vendored),
each in world space, keys of one name on several objects joined.  Per pair ``<src>_<dst>``:

- ``transfer_rel_energy_<pair>``: ‖ΔT − ΔA‖ / ‖ΔA‖ jointly over every key the target authored (peak at least
  5 % of its largest) and all its vertices; ``transfer_rel_median_<pair>`` the per-key median;
- ``transfer_parts_moved_frac_<pair>``: the share of the target's authored motion on its parts (every
  connected part but the skin; vertices in no triangle are no part) that the transfer reproduces,
  ``max(0, 1 − ‖ΔT − ΔA‖ / ‖ΔA‖)`` jointly over the same keys and the parts' vertices on objects that have
  shape keys (an object without keys authored nothing: Face Cap's eye meshes turn by their transforms)
  (``None`` for a target without authored part motion: FBHead is one surface and 661 loose vertices);
- ``transfer_blink_gap_frac_<pair>``: the lid gap left at eyeBlink weight 1 as a fraction of the target's open
  gap (widest remaining over widest open, ``core.authoring.contacts.gap_left``), the worse of L and R
  (``transfer_blink_gap_frac_authored_<head>``: the target's own authored blink);
- ``transfer_crossings_<pair>``: lid pairs crossed by some transferred key beyond those the target's own keys
  cross;
- ``transfer_s_<pair>``: landmarks + registration + transfer of every key + parts, seconds;
- ``transfer_report_status_<pair>``: the per-key checks' verdict (``core.authoring.quality``).

Landmarks for the registration come from the shapes both rigs share (the placed-landmark stand-in of the v1
suite).  The openings (eyes and inner lips) are the contours between the heads' named landmarks as a user
places them (``tools/landmarks/<head>.json``, ``core.authoring.named.contour_paths``), given to the transfer
(``core.authoring.contacts``); the blink metrics are measured on the target's lid contours.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

from bench_support import shared_data

LANDMARKS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "landmarks")

HEADS = {"facecap": ("facecap/facecap_decoded.glb", ("Mesh_2", "Mesh_0", "Mesh_1", "Mesh_3")),
         "fbhead": ("llf_fbhead/Live_Link_Face.blend", ("FBHead",)),
         "ict": ("ict_facekit/ict_facekit_expressions.glb", ("ICTFace",)),
         "rpm": ("rpm_brunette/brunette-t.glb", ("Wolf3D_Head", "EyeLeft", "EyeRight", "Wolf3D_Teeth"))}


def read_head(tag):
    """(neutral (n, 3), triangles (f, 3), deltas (k, n, 3), canonical names) of a whole head, world space."""
    head = read_head_keyed(tag)
    return None if head is None else head[0]


def read_head_keyed(tag):
    """(:func:`read_head`'s tuple, keyed (n,) bool: the vertex is on an object that has shape keys, the parts of
    part objects their rig moves by itself as the transfer keeps them, ``{vertex: ("still", reason)}``:
    ``bridge.authoring.parts.rig_kinds`` — Face Cap's eyes, turned by their parents' rotation), or None."""
    import bpy

    from shapespace.bridge import assets, shapekeys
    from shapespace.bridge.authoring.parts import rig_kinds
    from shapespace.core.authoring.mesh import triangle_parts
    from shapespace.core.names import canonical_name
    rel, objects = HEADS[tag]
    path = shared_data(rel, f"the {tag} head")
    if path is None:
        return None
    assets.load(path)
    verts, tris, models, off = [], [], [], 0
    for name in objects:
        ob = bpy.data.objects[name]
        me = ob.data
        M = np.array(ob.matrix_world)
        me.calc_loop_triangles()
        t = np.empty(len(me.loop_triangles) * 3, dtype=np.int32)
        me.loop_triangles.foreach_get("vertices", t)
        model = shapekeys.read_blendshape_model(ob) if me.shape_keys else None
        co = np.empty(len(me.vertices) * 3, dtype=np.float32)
        me.vertices.foreach_get("co", co)
        co = model.neutral if model is not None else co.reshape(-1, 3).astype(np.float64)
        verts.append(co @ M[:3, :3].T + M[:3, 3])
        tris.append(t.reshape(-1, 3).astype(np.int64) + off)
        models.append((model, M[:3, :3], off, len(co)))
        off += len(co)
    names = list(dict.fromkeys(canonical_name(n) for m, *_ in models if m is not None for n in m.names))
    D = np.zeros((len(names), off, 3))
    for model, L, o, n in models:
        for j, name in enumerate(model.names if model is not None else ()):
            D[names.index(canonical_name(name)), o:o + n] = model.deltas[j] @ L.T
    keyed = np.concatenate([np.full(n, model is not None) for model, _, _, n in models])
    V, TT = np.concatenate(verts), np.concatenate(tris)
    spans = [(bpy.data.objects[name], o, n) for name, (_, _, o, n) in zip(objects[1:], models[1:])]
    rigged = rig_kinds(bpy.data.objects[objects[0]], spans, triangle_parts(len(V), TT)[0])
    return (V, TT, D, names), keyed, rigged


def _openings(src_tag, S, ST, dst_tag, T, TT):
    """The eye and mouth openings between the heads' named landmarks (``tools/landmarks/<tag>.json``: indices of
    the head's first object, which starts the joined mesh)."""
    from shapespace.core.authoring import contacts, named
    ls = named.load_head_file(os.path.join(LANDMARKS, f"{src_tag}.json"))
    lt = named.load_head_file(os.path.join(LANDMARKS, f"{dst_tag}.json"))
    return contacts.openings_from_named(S, ST, ls, T, TT, lt)


def _scores(T, TD, TN, DT, SN, t_part, openings, keyed=None):
    from shapespace.core.authoring import contacts
    idx = {n: i for i, n in enumerate(SN)}
    peaks = np.abs(TD).reshape(len(TN), -1).max(axis=1)
    keep = [j for j, n in enumerate(TN) if n in idx and peaks[j] >= 0.05 * peaks.max()]
    A = TD[keep]
    X = np.stack([DT[idx[TN[j]]] for j in keep])
    per = np.linalg.norm((X - A).reshape(len(keep), -1), axis=1) / np.linalg.norm(A.reshape(len(keep), -1), axis=1)
    on = t_part > 0                 # the parts: not the skin (0), nor vertices in no triangle (−1: no part)
    if keyed is not None:           # nor objects without shape keys: nothing is authored there (Face Cap's eyes)
        on &= keyed
    authored = np.linalg.norm(A[:, on])
    parts_frac = max(0.0, 1.0 - np.linalg.norm(X[:, on] - A[:, on]) / authored) if authored > 0 else None
    out = {"transfer_rel_energy": float(np.linalg.norm(X - A) / np.linalg.norm(A)),
           "transfer_rel_median": float(np.median(per)), "transfer_parts_moved_frac": parts_frac}
    gaps, gaps_a, cross = [], [], 0
    for o in (o for o in openings if o.name.startswith("eye")):
        name = "eyeBlink" + {"L": "Left", "R": "Right"}[o.name[-1]]
        gaps.append(float(contacts.gap_left(T, DT[idx[name]][None], o.target_pairs)[0]))
        gaps_a.append(float(contacts.gap_left(T, TD[TN.index(name)][None], o.target_pairs)[0]))
        own = (contacts.gap_fractions(T, TD, o.target_pairs) < -0.05).any(axis=0)
        cross += int(((contacts.gap_fractions(T, DT, o.target_pairs) < -0.05).any(axis=0) & ~own).sum())
    out["transfer_blink_gap_frac"] = max(gaps) if gaps else None
    out["transfer_crossings"] = cross
    return out, (max(gaps_a) if gaps_a else None)


def transferred(src, dst, src_tag, dst_tag, kinds=None):
    """Landmarks → register → Transfer (with the named openings) → parts of one ordered pair: (deltas
    (k, n_t, 3) in the source's shape order, target part labels, openings, part plan, moved parts); ``kinds``:
    the target's parts set still by their rig (:func:`read_head_keyed`), as the transfer applies them."""
    from shapespace.core import authoring
    from shapespace.core.authoring import contacts, parts
    S, ST, SD, SN = src
    T, TT, TD, TN = dst
    s_part, _ = authoring.triangle_parts(S.shape[0], ST)
    t_part, _ = authoring.triangle_parts(T.shape[0], TT)
    lm = authoring.landmarks_from_shared_shapes(S, SD, SN, T, TD, TN, src_mask=s_part == 0, dst_mask=t_part == 0)
    reg = authoring.register(S, ST, T, TT, lm.value)
    openings = contacts.with_references(_openings(src_tag, S, ST, dst_tag, T, TT), S, SD, SN)
    tr = authoring.Transfer(S, ST, T, TT, reg.value, openings=openings)
    DT = tr.solve(SD)
    plan = parts.plan_for_transfer(S, ST, SD, SN, T, TT, DT, reg.value.part_map, kinds)
    DT, moved = parts.move_parts(plan, T, TT, DT, SN)
    return DT, t_part, openings, plan, moved


def pair(src, dst, src_tag, dst_tag, keyed=None, kinds=None):
    """Metrics of one ordered pair (keys without the pair suffix) and the target's authored blink gap
    (``keyed``: the target's vertices on objects with shape keys; ``kinds``: its parts its rig moves; see
    :func:`read_head_keyed`)."""
    from shapespace.core.authoring import quality
    S, ST, SD, SN = src
    T, TT, TD, TN = dst
    t0 = time.perf_counter()
    DT, t_part, openings, plan, moved = transferred(src, dst, src_tag, dst_tag, kinds)
    seconds = time.perf_counter() - t0
    _, _, status = quality.check_keys(S, SD, SN, T, DT, openings=openings, plan=plan, moved=moved, src_tris=ST,
                                      dst_tris=TT)
    m, authored_gap = _scores(T, TD, TN, DT, SN, t_part, openings, keyed)
    m["transfer_s"] = seconds
    m["transfer_report_status"] = status.name
    return m, authored_gap


def run(quick: bool = False) -> dict:
    """Every key of every ordered pair (``quick`` computes the same: the suite has no repetitions)."""
    loaded = {tag: read_head_keyed(tag) for tag in HEADS}
    heads = {tag: None if h is None else h[0] for tag, h in loaded.items()}
    out = {}
    for s in HEADS:
        for d in HEADS:
            if s == d or heads[s] is None or heads[d] is None:
                continue
            m, authored = pair(heads[s], heads[d], s, d, loaded[d][1], loaded[d][2])
            out.update({f"{k}_{s}_{d}": v for k, v in m.items()})
            out[f"transfer_blink_gap_frac_authored_{d}"] = authored
            print(f"bench transfer v2: {s} -> {d}: rel energy {m['transfer_rel_energy']:.3f} median "
                  f"{m['transfer_rel_median']:.3f} parts {m['transfer_parts_moved_frac']} blink gap "
                  f"{m['transfer_blink_gap_frac']} {m['transfer_s']:.1f} s", file=sys.stderr)
    return out
