"""Direct-manipulation benchmark (issue #3): solve speed vs peers, update overhead, artist effort."""
from __future__ import annotations

import csv
import os
import time

import numpy as np

import env

ASSETS = os.path.join(env.ROOT, "assets")


# ----------------------------------------------------------------------------- problems
def synthetic_model(n, p=3000, seed=0):
    """A production-shaped rig: n localised, smooth targets on a head-sized point cloud (cm)."""
    from shapespace.core.blendshape import BlendshapeModel
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(p, 3))
    pts = u / np.linalg.norm(u, axis=1, keepdims=True) * np.array([9.0, 11.0, 12.0])
    centres = pts[rng.integers(p, size=n)]
    radius = rng.uniform(2.0, 6.0, n)
    fall = np.exp(-np.sum((pts[None] - centres[:, None]) ** 2, axis=2) / radius[:, None] ** 2)
    direction = rng.normal(size=(n, 1, 3)) * rng.uniform(0.3, 1.5, (n, 1, 1))
    return BlendshapeModel(pts, fall[..., None] * direction, [f"t{i}" for i in range(n)])


def drag_problem(model, k, seed):
    from shapespace.core.manipulation import Pin, pin_positions
    rng = np.random.default_rng(seed)
    w_true = np.where(rng.random(model.n_targets) < 0.15, rng.uniform(0, 1, model.n_targets), 0.0)
    pins = [Pin.at_vertex(int(i)) for i in rng.choice(model.n_vertices, k, replace=False)]
    targets = pin_positions(model, pins, w_true) + rng.normal(0, 0.002 * model.scale, (k, 3))
    return pins, targets


def qp_matrices(model, pins, targets, w0, alpha=0.1, mu=0.001):
    """Eq. 4.5 as ½xᵀPx + qᵀx (for the peers), built independently of the solver's internals."""
    from shapespace.core.manipulation import NORMALISED_DIAGONAL, pin_matrix, pin_rest_positions
    unit = model.scale / NORMALISED_DIAGONAL
    R = pin_matrix(model, pins) / unit
    m = (targets - pin_rest_positions(model, pins)).reshape(-1) / unit
    n = model.n_targets
    P = 2 * (R.T @ R + (alpha + mu) * np.eye(n))
    q = -2 * (R.T @ m + alpha * w0)
    const = m @ m + alpha * w0 @ w0
    return P, q, const, R, m


def timed(fn, reps):
    best = []
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        best.append(time.perf_counter() - t)
    return float(np.median(best)) * 1e3, out


def peers(P, q, lo, hi, R, m, w0, alpha, mu, reps):
    import osqp
    import quadprog
    import scipy.sparse as sp
    from scipy.optimize import lsq_linear
    n = P.shape[0]
    res = {}

    def run_osqp():
        prob = osqp.OSQP()
        prob.setup(P=sp.triu(sp.csc_matrix(P)).tocsc(), q=q, A=sp.eye(n, format="csc"), l=lo, u=hi,
                   verbose=False, eps_abs=1e-9, eps_rel=1e-9, max_iter=200000, polishing=True)
        return prob.solve().x

    def run_quadprog():
        C = np.hstack([np.eye(n), -np.eye(n)])
        b = np.concatenate([lo, -hi])
        return quadprog.solve_qp(P, -q, C, b)[0]

    A = np.vstack([R, np.sqrt(alpha) * np.eye(n), np.sqrt(mu) * np.eye(n)])
    bb = np.concatenate([m, np.sqrt(alpha) * w0, np.zeros(n)])

    def run_lsq():
        return lsq_linear(A, bb, bounds=(lo, hi), method="bvls", tol=1e-12).x

    for name, fn in (("osqp", run_osqp), ("quadprog", run_quadprog), ("lsq_linear", run_lsq)):
        ms, x = timed(fn, reps)
        res[name] = (ms, np.clip(x, lo, hi))
    return res


def solve_speed(quick):
    from shapespace.bridge import assets, shapekeys
    import copy

    from shapespace.core.manipulation import DragSession, solve_drag
    import bpy

    reps = 3 if quick else 15
    models = {f"synthetic{n}": synthetic_model(n, seed=n) for n in (52, 150, 300, 675)}
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    models["facecap"] = shapekeys.read_blendshape_model(bpy.data.objects["Mesh_2"])
    ict = os.path.join(os.path.dirname(env.ROOT), "shared", "data", "ict_facekit", "ict_facekit_expressions.glb")
    if os.path.isfile(ict):
        assets.load(ict)
        models["ict"] = shapekeys.read_blendshape_model(bpy.data.objects["ICTFace"])
    out, gaps = {}, []
    for name, model in models.items():
        model.values[:] = 0.0
        for k in (1, 5, 20):
            pins, targets = drag_problem(model, k, seed=k)
            w0 = np.zeros(model.n_targets)
            lo, hi = model.slider_min, model.slider_max
            P, q, const, R, m = qp_matrices(model, pins, targets, w0)
            cold_ms, res = timed(lambda: solve_drag(model, pins, targets, w0), reps)
            # interactive: the same drag reached through 10 mouse moves, each warm-started
            path = [pins_t for pins_t in np.linspace(0.1, 1.0, 10)]
            rest = pin_rest(model, pins)
            started = DragSession()
            solve_drag(model, pins, rest, w0, session=started)

            def drag_sequence():
                session = copy.copy(started)
                for t in path:
                    last = solve_drag(model, pins, (1 - t) * rest + t * targets, w0, session=session)
                return last
            warm_ms, _ = timed(drag_sequence, reps)
            warm_ms /= len(path)
            pr = peers(P, q, lo, hi, R, m, w0, 0.1, 0.001, max(1, reps // 3))
            f = lambda x: 0.5 * x @ P @ x + q @ x + const  # noqa: E731
            best_obj = min(f(x) for _, x in pr.values())
            gaps.append(max(0.0, (f(res.weights) - best_obj) / abs(best_obj)))
            peer_best = min(ms for ms, _ in pr.values())
            tag = f"{name}_{model.n_targets}x{k}"
            out[f"solve_ms_{tag}"] = warm_ms
            out[f"solve_cold_ms_{tag}"] = cold_ms
            out[f"peer_best_ms_{tag}"] = peer_best
            for peer, (ms, _) in pr.items():
                out[f"{peer}_ms_{tag}"] = ms
    out["solve_ms_675x20"] = out["solve_ms_synthetic675_675x20"]
    out["solve_cold_ms_675x20"] = out["solve_cold_ms_synthetic675_675x20"]
    out["peer_best_ms_675x20"] = out["peer_best_ms_synthetic675_675x20"]
    out["speedup_vs_peer_675x20"] = out["peer_best_ms_675x20"] / out["solve_ms_675x20"]
    out["objective_rel_gap_max"] = float(max(gaps))
    return out


def pin_rest(model, pins):
    from shapespace.core.manipulation import pin_positions
    return pin_positions(model, pins, np.zeros(model.n_targets))


# ------------------------------------------------------------------------ update overhead
def update_overhead(quick):
    """One drag update in Blender (solve + write sliders + re-evaluation) minus Blender's own re-evaluation."""
    import package
    pkg = package.load()
    pkg.register()
    try:
        return _update_overhead(quick)
    finally:
        pkg.unregister()  # clean shutdown (bpy can crash at exit with handlers registered)


def _update_overhead(quick):
    import bpy
    from shapespace.bridge import assets, manipulation, meshes, shapekeys
    from shapespace.core.manipulation import DragSession, Pin, pin_positions
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    ob = bpy.data.objects["Mesh_2"]
    ob.data.shape_keys.animation_data.action = None
    model = shapekeys.read_blendshape_model(ob)
    model.values[:] = 0
    rng = np.random.default_rng(3)
    pins = [Pin.at_vertex(int(i)) for i in rng.choice(model.n_vertices, 8, replace=False)]
    for p_ in pins:
        manipulation.add_pin(ob, p_, pin_positions(model, [p_], model.values)[0])
    depsgraph = bpy.context.evaluated_depsgraph_get()
    steps = 20 if quick else 100
    goals = [rng.uniform(0, 0.8, model.n_targets) * (rng.random(model.n_targets) < 0.2) for _ in range(steps)]
    # Blender alone: write the sliders and re-evaluate
    t = time.perf_counter()
    for w in goals:
        shapekeys.write_slider_values(ob, model.names, w)
        meshes.evaluated_positions(ob, depsgraph)
    blender_ms = (time.perf_counter() - t) / steps * 1e3
    # full update: move pin 0's target, solve (warm), write, re-evaluate
    session = DragSession()
    zeros = np.zeros(model.n_targets)
    mouse_targets = [tuple(pin_positions(model, pins[:1], w)[0]) for w in goals]  # where the mouse goes
    t = time.perf_counter()
    for target in mouse_targets:
        ob.shapespace.pins[0].target = target
        manipulation.solve_pins(ob, model=model, w0=zeros, session=session)
        meshes.evaluated_positions(ob, depsgraph)
    full_ms = (time.perf_counter() - t) / steps * 1e3
    return {"update_blender_eval_ms": blender_ms, "update_full_ms": full_ms,
            "update_overhead_ms": full_ms - blender_ms}


# ---------------------------------------------------------------------------- artist effort
def simulate_artist(model, w_target, tol, prior=None, cap=25):
    """Drags until every vertex is within ``tol`` (model units) of the target expression."""
    from shapespace.core.manipulation import Pin, solve_drag
    goal = model.evaluate(w_target)
    w = np.zeros(model.n_targets)
    pins, targets = [], []
    for drags in range(cap + 1):
        err = np.linalg.norm(model.evaluate(w) - goal, axis=1)
        if err.max() <= tol:
            return drags
        if drags == cap:
            return cap
        v = int(np.argmax(err))
        pins.append(Pin.at_vertex(v))
        targets.append(goal[v])
        w = solve_drag(model, pins, np.array(targets), w, prior=prior).weights
    return cap


def llf_weights(names):
    """Live Link Face CSV columns mapped onto FBHead's sliders by name, (frames, n)."""
    from shapespace.core.names import match_channels
    path = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    header, data = rows[0], np.array([[float(x) for x in r[2:]] for r in rows[1:]])
    mapping, _, _ = match_channels(header[2:], names)
    out = np.zeros((len(data), len(names)))
    for j, src in enumerate(header[2:]):
        if src in mapping:
            out[:, names.index(mapping[src])] = data[:, j]
    return out


def artist_effort(quick):
    import bpy
    from shapespace.bridge import actions, assets, shapekeys
    from shapespace.core.manipulation import NORMALISED_DIAGONAL, train_prior

    datasets = {}
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"))
    ob = bpy.data.objects["Mesh_2"]
    model = shapekeys.read_blendshape_model(ob)
    curves = actions.shape_key_curves(ob)
    kx = np.unique(np.concatenate([actions.read_curve(fc)[0] for fc in curves.values()]))
    datasets["facecap"] = (model, actions.sample_shape_keys(ob, model.names, kx))
    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    ob = bpy.data.objects["FBHead"]
    model = shapekeys.read_blendshape_model(ob)
    datasets["llf"] = (model, llf_weights(model.names))
    out = {}
    for name, (model, frames) in datasets.items():
        model.values[:] = 0.0
        split = int(0.6 * len(frames))
        prior = train_prior(frames[:split], model.names)
        held = frames[split::3]
        if quick:
            held = held[::2]
        out[f"heldout_frames_{name}"] = len(held)
        out[f"sliders_set_mean_{name}"] = float(np.mean(np.sum(held > 0.01, axis=1)))
        for tol_mm in (3.0, 1.5):
            tol = tol_mm / 10.0 / NORMALISED_DIAGONAL * model.scale   # mm on a 30 cm head
            label = f"{tol_mm:g}mm"
            for mode, pr in (("plain", None), ("learned", prior)):
                counts = [simulate_artist(model, w, tol, pr) for w in held]
                out[f"drags_mean_{name}_{mode}_{label}"] = float(np.mean(counts))
                out[f"drags_median_{name}_{mode}_{label}"] = float(np.median(counts))
            out[f"drags_reduction_{name}_{label}"] = 1.0 - (out[f"drags_mean_{name}_learned_{label}"]
                                                           / out[f"drags_mean_{name}_plain_{label}"])
    return out


def run(quick=False) -> dict:
    import package
    package.load()
    metrics = {}
    metrics.update(solve_speed(quick))
    metrics.update(update_overhead(quick))
    metrics.update(artist_effort(quick))
    return metrics
