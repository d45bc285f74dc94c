"""Direct-manipulation benchmark (issue #3): solve speed vs peers, update overhead, artist effort; and (issue #17)
pin-and-drag at production scale: mouse moves, overlay redraws and Solve Pins on 27k–105k-vertex faces next to
Blender's own re-evaluation, measured in the same run.

The production faces are built here from the shared assets, read from ``../shared/data`` only (never copied):
ICT FaceKit as is (26,719 vertices, 57 keys); ICT subdivided once with bmesh (which interpolates the shape
keys, as Blender's Subdivide does: 105,569 vertices) and its keys duplicated with small variations to 150;
the Ready Player Me head under its armature, posed.
"""
from __future__ import annotations

import csv
import functools
import os
import time

import numpy as np

import env

ASSETS = os.path.join(env.ROOT, "assets")
SHARED = os.path.join(os.path.dirname(env.ROOT), "shared", "data")
ICT = os.path.join(SHARED, "ict_facekit", "ict_facekit_expressions.glb")
RPM = os.path.join(SHARED, "rpm_brunette", "brunette-t.glb")


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
    import copy

    import bpy

    from shapespace.bridge import assets, shapekeys
    from shapespace.core.manipulation import DragSession, solve_drag

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
            cold_ms, res = timed(functools.partial(solve_drag, model, pins, targets, w0), reps)
            # interactive: the same drag reached through 10 mouse moves, each warm-started
            path = [pins_t for pins_t in np.linspace(0.1, 1.0, 10)]
            rest = pin_rest(model, pins)
            started = DragSession()
            solve_drag(model, pins, rest, w0, session=started)

            def drag_sequence(model, pins, rest, targets, w0, started, path):
                session = copy.copy(started)
                for t in path:
                    last = solve_drag(model, pins, (1 - t) * rest + t * targets, w0, session=session)
                return last
            warm_ms, _ = timed(functools.partial(drag_sequence, model, pins, rest, targets, w0, started, path), reps)
            warm_ms /= len(path)
            pr = peers(P, q, lo, hi, R, m, w0, 0.1, 0.001, max(1, reps // 3))
            f = lambda x, P=P, q=q, const=const: 0.5 * x @ P @ x + q @ x + const  # noqa: E731
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
    # the one pass over a model's deltas a cold solve no longer repeats (finite check, inert keys; kept on the model)
    from shapespace.core.manipulation import rig_facts
    fresh = synthetic_model(675, seed=675)
    t = time.perf_counter()
    rig_facts(fresh)
    out["rig_check_ms_675"] = (time.perf_counter() - t) * 1e3
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


# ------------------------------------------------------------------- production scale (issue #17)
def _ict_face():
    import bpy

    from shapespace.bridge import assets
    assets.load(ICT)
    return bpy.data.objects["ICTFace"]


def _ict_subdivided(n_keys=150, seed=17):
    """ICT subdivided once (bmesh interpolates every shape key) and its keys duplicated with variations."""
    import bmesh
    ob = _ict_face()
    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=1, use_grid_fill=True)
    bm.to_mesh(ob.data)
    bm.free()
    ob.data.update()
    blocks = ob.data.shape_keys.key_blocks
    size = 3 * len(ob.data.vertices)
    basis, buf = np.empty(size, np.float32), np.empty(size, np.float32)
    blocks[0].points.foreach_get("co", basis)
    sources = [kb.name for kb in blocks[1:]]
    rng = np.random.default_rng(seed)
    i = 0
    while len(blocks) < n_keys + 1:
        name = sources[i % len(sources)]
        i += 1
        blocks[name].points.foreach_get("co", buf)
        delta = (buf - basis).reshape(-1, 3)
        gain = rng.uniform(0.7, 1.3) * (1.0 + 0.1 * np.sin(rng.uniform(0.5, 2.0) * delta[:, :1]))
        kb = ob.shape_key_add(name=f"{name}_var{i}", from_mix=False)
        kb.points.foreach_set("co", (basis.reshape(-1, 3) + delta * gain).astype(np.float32).ravel())
        kb.value = 0.0
    ob.data.update()
    return ob


def _rpm_posed():
    import bpy

    from shapespace.bridge import assets, skin
    assets.load(RPM)
    ob = bpy.data.objects["Wolf3D_Head"]
    arm = skin.armature_modifiers(ob)[0].object
    for bone, rot in (("Head", (0.3, 0.2, -0.25)), ("Neck", (0.1, -0.15, 0.05)), ("Spine2", (0.05, 0.0, 0.1))):
        pb = arm.pose.bones[bone]
        pb.rotation_mode = "XYZ"
        pb.rotation_euler = rot
    bpy.context.view_layer.update()
    return ob


PRODUCTION_CASES = {"ict27k": _ict_face, "ict100k": _ict_subdivided, "rpm_posed": _rpm_posed}


def _init_gpu():
    """Background Blender unlocks the gpu module once a GPU context exists: a tiny Workbench render makes one."""
    import bpy
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 8
    cam = bpy.data.objects.new("GpuInitCam", bpy.data.cameras.new("GpuInitCam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    bpy.ops.render.render()
    bpy.data.objects.remove(cam)


def _drag_setup(ob, n_still=4, seed=5):
    """Zero sliders, a dragged pin at the jaw and ``n_still`` stationary pins; the drag's world-space goal."""
    import bpy

    from shapespace.bridge import manipulation, meshes, shapekeys
    from shapespace.core.manipulation import Pin
    bpy.context.view_layer.objects.active = ob
    key = ob.data.shape_keys
    if key.animation_data is not None:
        key.animation_data.action = None
    names = shapekeys.slider_names(ob)
    shapekeys.write_slider_values(ob, names, np.zeros(len(names)))
    ob.shapespace.mode = "DIRECT"
    manipulation.clear_pins(ob)
    t = time.perf_counter()
    model = manipulation.rig_model(ob)
    read_ms = (time.perf_counter() - t) * 1e3
    jaw = model.index("jawOpen")
    v = int(np.argmax(np.linalg.norm(model.deltas[jaw], axis=1)))
    manipulation.add_pin(ob, Pin.at_vertex(v))
    moving = np.flatnonzero(np.abs(model.deltas).max(axis=(0, 2)) > 1e-3 * model.scale)
    rng = np.random.default_rng(seed)
    for u in rng.choice(moving, n_still, replace=False):
        manipulation.add_pin(ob, Pin.at_vertex(int(u)), stationary=True)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    start = meshes.to_world(ob, manipulation.deformed_pin_positions(ob, depsgraph)[:1])[0]
    goal_w = np.zeros(model.n_targets)
    goal_w[jaw] = 0.6
    for name in ("mouthSmile_L", "mouthSmileLeft"):
        if name in model.names:
            goal_w[model.index(name)] = 0.4
    manipulation.write_sliders(ob, model.names, goal_w)
    goal = meshes.to_world(ob, manipulation.deformed_pin_positions(ob, depsgraph)[:1])[0]
    manipulation.write_sliders(ob, model.names, np.zeros(model.n_targets))
    return model, start, goal, read_ms


def _mouse_path(start, goal, moves):
    """A mouse path from the pin to the goal: a straight line with a small sideways wobble."""
    t = np.linspace(0.0, 1.0, moves + 1)[1:]
    side = np.cross(goal - start, (0.0, 0.0, 1.0))
    side = side / (np.linalg.norm(side) + 1e-30) * 0.05 * np.linalg.norm(goal - start)
    return start + t[:, None] * (goal - start) + np.sin(6 * np.pi * t)[:, None] * side


def _overlay_view(ob):
    """View and projection matrices that frame ``ob`` (orthographic, looking along +Y)."""
    from mathutils import Matrix

    from shapespace.bridge import meshes
    pts = meshes.to_world(ob, np.array([list(c) for c in ob.bound_box]))
    lo, hi = pts.min(0), pts.max(0)
    centre, half = (lo + hi) / 2, float((hi - lo).max()) * 0.75 + 1e-6
    view = Matrix(((1, 0, 0, -centre[0]), (0, 0, 1, -centre[2]), (0, -1, 0, centre[1] - 10 * half), (0, 0, 0, 1)))
    proj = Matrix(((1 / half, 0, 0, 0), (0, 1 / half, 0, 0), (0, 0, -1 / (20 * half), 0), (0, 0, 0, 1)))
    return view, proj


def _timed_drag(ob, path, offscreen):
    """One scripted drag through the bridge calls of the Drag Pins tool.  Per mouse move: the move's time;
    then Blender alone making the same slider change (sliders put back to the previous move's, untimed, then
    this move's written in one bulk write and one depsgraph update, timed) — paired with the move it follows,
    so both see the same machine load; then the overlay redraw (the draw callback into ``offscreen``)."""
    import bpy
    import gpu

    from shapespace.bridge import manipulation
    from shapespace.ui import overlay
    view, proj = _overlay_view(ob)
    key = ob.data.shape_keys
    blocks = key.key_blocks
    before = np.empty(len(blocks), dtype=np.float32)
    blocks.foreach_get("value", before)
    now = before.copy()
    drag = manipulation.Drag(ob)
    drag.grab(ob, 0)
    move_ms, reeval_ms, draw_ms = [], [], []
    for point in path:
        t = time.perf_counter()
        drag.move(ob, bpy.context.evaluated_depsgraph_get(), point)
        move_ms.append((time.perf_counter() - t) * 1e3)
        blocks.foreach_get("value", now)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        with manipulation.RIGS.own_write(ob):       # the benchmark's own writes: they leave the rig as it was
            blocks.foreach_set("value", before)
            key.update_tag()
            depsgraph.update()
            t = time.perf_counter()
            blocks.foreach_set("value", now)
            key.update_tag()
            depsgraph.update()
            reeval_ms.append((time.perf_counter() - t) * 1e3)
        before[:] = now
        with offscreen.bind():
            with gpu.matrix.push_pop():
                gpu.matrix.load_matrix(view)
                with gpu.matrix.push_pop_projection():
                    gpu.matrix.load_projection_matrix(proj)
                    t = time.perf_counter()
                    overlay._draw_callback()
                    draw_ms.append((time.perf_counter() - t) * 1e3)
    drag.cancel(ob)
    return move_ms, reeval_ms, draw_ms


def _timed_solve_op(ob, start, goal, calls):
    """The Solve Pins operator moving pin 0 to world-space points: first call and the median of later calls.

    The call includes Blender's undo step and the one depsgraph update of the slider write; anything still
    to evaluate afterwards (the viewport redraw's work) is done between calls, untimed.
    """
    import bpy
    times = []
    for i in range(calls + 1):
        point = start + (goal - start) * (0.3 + 0.7 * i / calls)
        t = time.perf_counter()
        bpy.ops.shapespace.solve_pins(pin=0, target=tuple(point), space="WORLD")
        times.append((time.perf_counter() - t) * 1e3)
        bpy.context.evaluated_depsgraph_get()
    return times[0], float(np.median(times[1:]))


def _timed_drag_start(ob, point, reps):
    """Mouse-down on the face: the drag reads the (cached) rig, the ray picks the surface, the pin is added."""
    import bpy

    from shapespace.bridge import manipulation, meshes
    size = float(np.ptp(meshes.to_world(ob, np.array([list(c) for c in ob.bound_box])), axis=0).max())
    origin = point + np.array([0.0, -3.0 * size, 0.0])
    times = []
    for _ in range(reps):
        depsgraph = bpy.context.evaluated_depsgraph_get()
        t = time.perf_counter()
        drag = manipulation.Drag(ob)
        pin, _ = manipulation.surface_pin(ob, depsgraph, origin, point - origin)
        index = manipulation.add_pin(ob, pin, None, model=drag.model)
        drag.grab(ob, index, created=True)
        times.append((time.perf_counter() - t) * 1e3)
        drag.cancel(ob)
    return float(np.median(times))


def production_case(name, quick):
    """Every issue #17 metric of one production face."""
    import bpy
    import gpu

    from shapespace.bridge import manipulation, shapekeys
    bpy.ops.wm.read_factory_settings(use_empty=True)
    _init_gpu()
    ob = PRODUCTION_CASES[name]()
    model, start, goal, read_ms = _drag_setup(ob)
    moves, reps = 60, (1 if quick else 5)
    path = _mouse_path(start, goal, moves)
    offscreen = gpu.types.GPUOffScreen(256, 256)
    move_ms, draw_ms, reeval_ms = [], [], []
    load = os.getloadavg()[0]
    try:
        for _ in range(reps):
            m, r, d = _timed_drag(ob, path, offscreen)
            move_ms += m
            reeval_ms += r
            draw_ms += d
    finally:
        offscreen.free()
    first_op, op_ms = _timed_solve_op(ob, start, goal, 5 if quick else 20)
    start_ms = _timed_drag_start(ob, start, 3 if quick else 10)
    # a slider moved by hand: the next use verifies the rig (checksum) instead of reading it again
    shapekeys.write_slider_values(ob, [model.names[0]], [0.3])
    bpy.context.evaluated_depsgraph_get()
    verified = manipulation.RIGS.verifications
    t = time.perf_counter()
    manipulation.rig_model(ob)
    verify_ms = (time.perf_counter() - t) * 1e3
    assert manipulation.RIGS.verifications == verified + 1
    tag = name
    return {f"drag_move_ms_{tag}": float(np.median(move_ms)),
            f"drag_move_ms_p99_{tag}": float(np.percentile(move_ms, 99)),
            f"overlay_redraw_ms_{tag}": float(np.median(draw_ms)),
            f"overlay_redraw_ms_p99_{tag}": float(np.percentile(draw_ms, 99)),
            f"blender_reeval_ms_{tag}": float(np.median(reeval_ms)),
            f"drag_overhead_ms_{tag}": float(np.median(np.subtract(move_ms, reeval_ms))),   # paired samples
            f"solve_pins_op_ms_{tag}": op_ms,
            f"solve_pins_op_first_ms_{tag}": first_op,
            f"drag_start_ms_{tag}": start_ms,
            f"model_read_ms_{tag}": read_ms,
            f"rig_verify_ms_{tag}": verify_ms,
            f"load_average_{tag}": load,
            f"vertices_{tag}": int(model.n_vertices),
            f"keys_{tag}": int(model.n_targets)}


def production_scale(quick):
    import package
    pkg = package.load()
    pkg.register()
    try:
        out = {}
        for name in PRODUCTION_CASES:
            out.update(production_case(name, quick))
        return out
    finally:
        pkg.unregister()


def run(quick=False) -> dict:
    import package
    package.load()
    metrics = {}
    metrics.update(solve_speed(quick))
    metrics.update(update_overhead(quick))
    metrics.update(production_scale(quick))
    metrics.update(artist_effort(quick))
    return metrics
