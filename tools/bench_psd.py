"""Pose-space corrective benchmark (issue #4): quality vs examples, inversion round trip, speed."""
from __future__ import annotations

import os
import time

import numpy as np

from bench_support import shared_data  # noqa: E402

REGIONS = {  # region: (asset, mesh, joints) — rpm_brunette is read from shared/ only (non-commercial)
    "cesium_arm": ("cesium_man/CesiumMan.glb", "Cesium_Man",
                   ["Skeleton_arm_joint_L__4_", "Skeleton_arm_joint_L__3_", "Skeleton_arm_joint_L__2_"]),
    "robot_hand": ("robot_expressive/RobotExpressive.glb", "HandL_1",
                   ["Palm1L", "Palm2L", "Palm3L", "IndexL", "Middle1L", "Ring1L", "ThumbL", "Thumb2L"]),
    "rpm_hand": ("rpm_brunette/brunette-t.glb", "Wolf3D_Body",
                 ["LeftHand", "LeftHandThumb1", "LeftHandThumb2", "LeftHandIndex1", "LeftHandIndex2",
                  "LeftHandMiddle1", "LeftHandMiddle2", "LeftHandRing1", "LeftHandRing2", "LeftHandPinky1",
                  "LeftHandPinky2"]),
}
KS = (2, 4, 8, 16, 32)
N_TRAIN = max(KS)
#: Curves: skinning only, PSD, Shape-by-Example, weighted PSD (skin-weighted distance), weighted PSD's "Blended"
#: option (per region by leave-one-out: skin-weighted, blended with the global distance, or bone pairs) and its
#: "Bone Pairs" option.  ``wpsd_examples_for_psd32_<region>`` is the Blended option's; the skin-weighted one's is
#: ``wpsd_skin_examples_for_psd32_<region>``, the Bone Pairs one's ``wpsd_pairs_examples_for_psd32_<region>``.
METHOD_CURVES = ("lbs", "psd", "sbe", "wpsd", "wpsd_blend", "wpsd_pairs")


def _rig(asset, mesh_name):
    """Rest mesh, skinning (one Armature modifier), bone rest matrices and parents, via the bridge."""
    import bpy

    from shapespace.bridge import assets, meshes, skin
    assets.load(shared_data(asset, asset))
    ob = bpy.data.objects[mesh_name]
    rig = skin.read_skinning(ob)
    arm = skin.armature_modifiers(ob)[0].object
    bones = arm.data.bones
    index = {b.name: i for i, b in enumerate(bones)}
    parents = [index[b.parent.name] if b.parent else -1 for b in bones]
    rest = meshes.vertex_positions(ob.data).astype(np.float64)
    return ob, arm, rig, rest, parents


def _bends(rng, n, max_angle):
    """One bend per joint about its local X axis (a finger curl / elbow bend), angle in [0, max_angle]."""
    angle = rng.uniform(0.0, max_angle, n)
    return np.stack([np.cos(angle / 2), np.sin(angle / 2), np.zeros(n), np.zeros(n)], axis=1)


def _random_rotations(rng, n, max_angle):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(0.2, 1.0, n) * max_angle
    return np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], axis=1)


class Region:
    def __init__(self, name):
        from shapespace.core.posespace.readers import PoseReader, quaternion_to_matrix
        asset, mesh, joints = REGIONS[name]
        self.ob, self.arm, self.rig, self.rest, self.parents = _rig(asset, mesh)
        d = self.rig.deformers[0]
        self.bone_names = d.bone_names
        self.joints = [self.bone_names.index(j) for j in joints]
        self.readers = [PoseReader("rotation", j) for j in joints]
        w = d.weights.effective()
        in_region = np.isin(d.weights.bone_index, self.joints)
        self.verts = np.flatnonzero((w * in_region).sum(axis=1) > 0.01)
        self.size = float(np.linalg.norm(np.ptp(self.rest, axis=0)))
        self.q2m = quaternion_to_matrix
        # weighted-PSD inputs: influences mapped to region joints (others → −1)
        remap = np.full(len(self.bone_names) + 1, -1)
        remap[self.joints] = np.arange(len(self.joints))
        self.wpsd_groups = remap[d.weights.bone_index]
        self.wpsd_weights = np.where(self.wpsd_groups >= 0, d.weights.weight, 0.0)
        self.columns = [np.arange(9 * i, 9 * i + 9) for i in range(len(joints))]
        from shapespace.core.posespace.pairs import bone_pairs
        self.pairs = bone_pairs(self.readers, self.bone_names, d.rest, self.parents, self.wpsd_groups,
                                self.wpsd_weights)

    def poses(self, quats):
        from shapespace.core.skinning import forward_kinematics
        d = self.rig.deformers[0]
        basis = np.broadcast_to(np.eye(4), (len(self.bone_names), 4, 4)).copy()
        for j, q in zip(self.joints, quats):
            basis[j, :3, :3] = self.q2m(q)
        return forward_kinematics(d.rest, self.parents, basis)

    def features(self, quats):
        from shapespace.core.posespace.readers import pose_features
        return pose_features(self.readers, list(quats))

    def deform(self, coords, pose, dqs):
        from shapespace.core.skinning import deform
        self.rig.deformers[0].preserve_volume = dqs
        return deform(coords, self.rig, [pose])


def _bulge(region, quats):
    """A second nonlinear reference: a bulge driven by the bend of the first two joints (rest space)."""
    from shapespace.core.posespace.readers import quaternion_distance
    ident = np.array([1.0, 0, 0, 0])
    a = np.sin(quaternion_distance(quats[0], ident) / 2) * np.sin(quaternion_distance(quats[1], ident) / 2)
    head = region.rig.deformers[0].rest[region.joints[1], :3, 3]
    to_mesh = np.linalg.inv(region.rig.mesh_world) @ region.rig.deformers[0].armature_world
    head = to_mesh[:3, :3] @ head + to_mesh[:3, 3]
    off = region.rest - head
    local = float(np.linalg.norm(np.ptp(region.rest[region.verts], axis=0)))
    fall = np.exp(-np.sum(off ** 2, axis=1) / (0.15 * local) ** 2)
    return 0.05 * local * a * fall[:, None] * off / (np.linalg.norm(off, axis=1, keepdims=True) + 1e-12)


def _examples(region, rng, ref, n_train=N_TRAIN, n_test=100):
    """One draw of the benchmark: ``n_train`` example poses (features and rest-space correctives) and
    ``n_test`` held-out test poses (features, skinning pose, true deformed mesh), every joint bent about its
    own axis independently; ``ref`` "dqs" (the dual-quaternion look) or "bulge"."""
    from shapespace.core.posespace.inversion import invert_deformation
    nj = len(region.joints)
    train_q = [_bends(rng, nj, 1.3) for _ in range(n_train)]
    test_q = [_bends(rng, nj, 1.3) for _ in range(n_test)]

    def truth(q, pose):
        if ref == "dqs":
            return region.deform(region.rest, pose, True)
        return region.deform(region.rest + _bulge(region, q), pose, False)

    def corrective(q):
        pose = region.poses(q)
        if ref == "bulge":
            return _bulge(region, q)
        inv = invert_deformation(lambda x: region.deform(x, pose, False), region.rest, truth(q, pose))
        return inv.corrective
    train_X = np.stack([region.features(q) for q in train_q])
    train_D = np.stack([corrective(q) for q in train_q])
    tests = [(region.features(q), region.poses(q), truth(q, region.poses(q))) for q in test_q]
    return train_X, train_D, tests


def _fit(region, method, X, D):
    """The model of ``method`` (psd, sbe, wpsd, wpsd_blend, wpsd_pairs) on the examples, or None for skinning only."""
    from shapespace.core.posespace.psd import train_psd
    if method == "lbs":
        return None
    kw = {}
    if method.startswith("wpsd"):
        kw = dict(vertex_groups=region.wpsd_groups, vertex_weights=region.wpsd_weights,
                  group_columns=region.columns)
    if method == "wpsd_blend":       # per region: skin-weighted, blended with the global distance, or bone pairs
        kw.update(blend="auto", pairs=region.pairs)
    if method == "wpsd_pairs":       # the bone-pair distance everywhere
        kw.update(blend="pairs", pairs=region.pairs)
    return train_psd(X, D, method[:4], **kw)


def _errors(region, model, tests):
    """Per test pose and region vertex: distance of the skinned result to the truth / the mesh's size."""
    errs = []
    for x, pose, want in tests:
        coords = region.rest if model is None else region.rest + model.evaluate(x)
        got = region.deform(coords, pose, False)
        errs.append(np.linalg.norm(got - want, axis=1)[region.verts] / region.size)
    return np.array(errs)


def quality(quick):
    out = {}
    curves = {}
    for name in [r for r in REGIONS if shared_data(REGIONS[r][0], f"the {r} region")]:
        region = Region(name)
        for ref in ("dqs", "bulge"):
            train_X, train_D, tests = _examples(region, np.random.default_rng(11), ref)
            tag = f"{name}" if ref == "dqs" else f"{name}_bulge"
            for method in METHOD_CURVES:
                for K in KS:
                    if method == "lbs" and K != KS[0]:
                        out[f"err_mean_lbs_k{K}_{tag}"] = out[f"err_mean_lbs_k{KS[0]}_{tag}"]
                        out[f"err_max_lbs_k{K}_{tag}"] = out[f"err_max_lbs_k{KS[0]}_{tag}"]
                        continue
                    errs = _errors(region, _fit(region, method, train_X[:K], train_D[:K]), tests)
                    out[f"err_mean_{method}_k{K}_{tag}"] = float(errs.mean())
                    out[f"err_max_{method}_k{K}_{tag}"] = float(errs.max())
            psd32 = out[f"err_mean_psd_k{max(KS)}_{tag}"]
            for method, key in (("wpsd_blend", "wpsd_examples_for_psd32"), ("wpsd", "wpsd_skin_examples_for_psd32"),
                                ("wpsd_pairs", "wpsd_pairs_examples_for_psd32")):
                reach = [K for K in KS if out[f"err_mean_{method}_k{K}_{tag}"] <= psd32]
                out[f"{key}_{tag}"] = float(min(reach)) if reach else float("inf")
            curves[tag] = {m: [out[f"err_mean_{m}_k{K}_{tag}"] for K in KS] for m in METHOD_CURVES}
        if name in DRAW_REGIONS:
            out.update(draw_spread(region, name))
    return out, curves


#: Draw spread (#16): the hands' examples-for-PSD32 measured on independent draws of examples and test poses
#: (seed 11 is the benchmark's own draw), so a goal can be told from the luck of one draw.
DRAW_REGIONS = ("robot_hand", "rpm_hand")
DRAW_SEEDS = (11, 1, 2, 3, 4, 5, 6, 7, 8, 9)


def draw_spread(region, name):
    """For each draw: weighted PSD's mean error at 8 and 16 examples over plain PSD's at 32 (the Blended, the
    skin-weighted and the Bone Pairs distance).  Keys:
    ``wpsd_over_psd32_k<K>_<median|min|max>_<region>[_skin|_pairs]`` and
    ``wpsd_draws_reaching_psd32_k<K>_<region>[_skin|_pairs]`` (how many of the draws reach PSD32's error)."""
    ratios = {}
    for seed in DRAW_SEEDS:
        X, D, tests = _examples(region, np.random.default_rng(seed), "dqs")
        psd32 = _errors(region, _fit(region, "psd", X, D), tests).mean()
        for method, suffix in (("wpsd_blend", ""), ("wpsd", "_skin"), ("wpsd_pairs", "_pairs")):
            for K in (8, 16):
                err = _errors(region, _fit(region, method, X[:K], D[:K]), tests).mean()
                ratios.setdefault((K, suffix), []).append(float(err / psd32))
    out = {"wpsd_draws": len(DRAW_SEEDS)}
    for (K, suffix), r in ratios.items():
        r = np.array(r)
        out[f"wpsd_over_psd32_k{K}_median_{name}{suffix}"] = float(np.median(r))
        out[f"wpsd_over_psd32_k{K}_min_{name}{suffix}"] = float(r.min())
        out[f"wpsd_over_psd32_k{K}_max_{name}{suffix}"] = float(r.max())
        out[f"wpsd_draws_reaching_psd32_k{K}_{name}{suffix}"] = int(np.sum(r <= 1.0))
    return out


def plot(curves, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(curves), figsize=(4.2 * len(curves), 3.6), squeeze=False)
    for ax, (tag, c) in zip(axes[0], curves.items()):
        labels = {"wpsd_blend": "WPSD blended (auto)", "wpsd_pairs": "WPSD bone pairs"}
        for m, style in (("lbs", "k--"), ("psd", "o-"), ("sbe", "s-"), ("wpsd", "^-"), ("wpsd_blend", "v-"),
                         ("wpsd_pairs", "D-")):
            ax.plot(KS, c[m], style, label=labels.get(m, m.upper()))
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_title(tag)
        ax.set_xlabel("examples K")
        ax.set_ylabel("mean vertex error / bbox diagonal")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def roundtrip():
    """Apply through the real Blender pipeline; error of Blender's evaluated mesh vs the sculpt."""
    import bpy

    from shapespace.bridge import meshes, posespace, skin
    out = {}
    for label, dqs, bbone in (("lbs", False, False), ("dqs", True, False), ("bbone", False, True)):
        ob, arm, _, _, _ = _rig(*REGIONS["cesium_arm"][:2])
        arm.animation_data.action = None
        bone = REGIONS["cesium_arm"][2][1]
        if bbone:
            bpy.context.view_layer.objects.active = arm
            bpy.ops.object.mode_set(mode="EDIT")
            arm.data.edit_bones[bone].bbone_segments = 6
            bpy.ops.object.mode_set(mode="OBJECT")
            arm.pose.bones[bone].bbone_curveinx = 0.05
        for m in skin.armature_modifiers(ob):
            m.use_deform_preserve_volume = dqs
        pb = arm.pose.bones[bone]
        pb.rotation_mode = "QUATERNION"
        pb.rotation_quaternion = (0.85, 0.35, 0.3, 0.2)
        bpy.context.view_layer.update()
        name = posespace.add_example(ob)
        copy = ob.shapespace_psd.examples[name].sculpt
        co = meshes.vertex_positions(copy.data).astype(np.float64)
        rng = np.random.default_rng(5)
        size = float(np.linalg.norm(np.ptp(co, axis=0)))
        co += 0.01 * size * rng.normal(size=co.shape) * (rng.random(len(co)) < 0.2)[:, None]
        wanted = meshes.to_local(ob, meshes.to_world(copy, co))
        t = time.perf_counter()
        posespace.apply_example(ob, name, wanted)
        out[f"apply_s_{label}"] = time.perf_counter() - t
        posespace.preview(ob)
        got = meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)
        out[f"roundtrip_err_rel_{label}"] = float(np.abs(got - wanted).max() / size)
    return out


def _eval_ms(model, poses, n, fastest=None):
    """Median milliseconds of one fast evaluation (poses cycled); ``fastest`` (a list) receives the minimum,
    the closest this shared machine comes to a quiet one."""
    times = []
    for i in range(n):
        x = poses[i % len(poses)]
        t = time.perf_counter()
        model.evaluate_fast(x)
        times.append(time.perf_counter() - t)
    if fastest is not None:
        fastest.append(float(np.min(times) * 1e3))
    return float(np.median(times) * 1e3)


def _smooth_wpsd_case(rng, p, n_ex, joints):
    """Weighted-PSD inputs whose correctives are smooth functions of the pose, and 10 test poses."""
    from shapespace.core.posespace.readers import PoseReader, pose_features
    readers = [PoseReader("rotation", f"b{j}") for j in range(joints)]
    axes = np.eye(3)[rng.integers(0, 3, joints)]

    def feats(angles):
        q = np.concatenate([np.cos(angles / 2)[:, None], np.sin(angles / 2)[:, None] * axes], axis=1)
        return pose_features(readers, list(q))
    angles = rng.uniform(0, 1.3, (n_ex, joints))
    X = np.stack([feats(a) for a in angles])
    coords = rng.normal(size=(p, 3))
    size = float(np.linalg.norm(np.ptp(coords, axis=0)))
    gi = rng.integers(0, joints, size=(p, 4))
    gw = rng.dirichlet(np.full(4, 0.5), size=p)
    dirs = rng.normal(size=(p, 4, 3))

    def corrective(a):
        th = a[gi]
        f = (1 - np.cos(th)) + 0.5 * np.sin(th) * np.sin(a[gi[:, [1, 2, 3, 0]]])
        return 0.005 * size * np.einsum("pm,pm,pmc->pc", gw, f, dirs)
    D = np.stack([corrective(a) for a in angles])
    poses = [feats(rng.uniform(0, 1.3, joints)) for _ in range(10)]
    return X, D, gi, gw, [np.arange(9 * j, 9 * j + 9) for j in range(joints)], poses, size


def _pairs_speed(X, D, gi, gw, cols, poses, size, reps):
    """The same 30k-vertex, 30-example case with the Bone Pairs distance, the 20 joints in a binary tree:
    every shared bone pair's relative rotation computed per pose, more terms per vertex."""
    from shapespace.core.posespace.pairs import bone_pairs
    from shapespace.core.posespace.psd import train_psd
    from shapespace.core.posespace.readers import PoseReader
    joints = len(cols)
    names = [f"b{j}" for j in range(joints)]
    parents = [-1] + [(j - 1) // 2 for j in range(1, joints)]
    pairs = bone_pairs([PoseReader("rotation", n) for n in names], names, np.tile(np.eye(4), (joints, 1, 1)),
                       parents, gi, gw)
    model = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=cols, blend="pairs",
                      pairs=pairs)
    model.prepare_fast(size)
    errs = [float(np.abs(model.evaluate_fast(x) - model.evaluate(x)).max()) for x in poses]
    return {"wpsd_eval_ms_30k_n30_pairs": _eval_ms(model, poses, reps * 10),
            "wpsd_eval_err_rel_vs_f64_pairs": max(errs) / size, "wpsd_eval_bone_pairs_30k": pairs.n_pairs}


def speed(quick):
    from scipy.interpolate import RBFInterpolator

    from shapespace.core import rbf
    from shapespace.core.posespace.inversion import invert_deformation
    from shapespace.core.posespace.psd import train_psd
    from shapespace.core.skinning import ArmatureDeform, SkinningRig, SkinWeights, deform
    rng = np.random.default_rng(0)
    p, n_ex, joints = 30000, 30, 20
    reps = 3 if quick else 10
    X = rng.normal(size=(n_ex, 9 * joints)) * 0.3
    D = rng.normal(size=(n_ex, p, 3)) * 0.01
    gi = rng.integers(0, joints, size=(p, 4))
    gw = rng.dirichlet(np.ones(4), size=p)
    cols = [np.arange(9 * j, 9 * j + 9) for j in range(joints)]
    t = time.perf_counter()
    model = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=cols)
    out = {"wpsd_train_s_30k_n30": time.perf_counter() - t}
    x = rng.normal(size=9 * joints) * 0.3
    # random correctives (no relation to the pose): the worst case, every vertex system amplifies ~1000×
    coords = rng.normal(size=(p, 3))
    size = float(np.linalg.norm(np.ptp(coords, axis=0)))
    model.prepare_fast(size)
    out["wpsd_eval_ms_30k_n30_random"] = _eval_ms(model, [x], reps * 10)
    out["wpsd_eval_float32_share_random"] = model._fast.idx32.size / p
    out["wpsd_eval_err_rel_vs_f64_random"] = float(np.abs(model.evaluate_fast(x) - model.evaluate(x)).max()) / size
    t = time.perf_counter()
    for _ in range(reps):
        model.evaluate(x)
    out["wpsd_eval_ms_30k_n30_float64"] = (time.perf_counter() - t) / reps * 1e3
    # correctives that are smooth functions of the pose (as sculpted correctives are): 20 joints bending
    # about their own axes, 4 influences per vertex, correctives 2 % of the mesh size
    X, D, gi, gw, cols, poses, size = _smooth_wpsd_case(rng, p, n_ex, joints)
    model = train_psd(X, D, "wpsd", vertex_groups=gi, vertex_weights=gw, group_columns=cols)
    model.prepare_fast(size)
    fastest = []
    out["wpsd_eval_ms_30k_n30"] = _eval_ms(model, poses, reps * 10, fastest)
    out["wpsd_eval_ms_30k_n30_min"] = fastest[0]
    out["wpsd_eval_load_avg_1min"] = os.getloadavg()[0]
    out["wpsd_eval_float32_share"] = model._fast.idx32.size / p
    errs = [float(np.abs(model.evaluate_fast(x) - model.evaluate(x)).max()) for x in poses]
    out["wpsd_eval_err_rel_vs_f64"] = max(errs) / size
    out["wpsd_eval_err_rel_vs_f64_of_corrective"] = max(errs) / float(np.abs(D).max())
    out["wpsd_eval_ridged_share"] = model.diagnostics["ridged_vertices"] / p
    out.update(_pairs_speed(X, D, gi, gw, cols, poses, size, reps))
    # inversion of a 30k-vertex sculpt under 20-bone linear blend skinning
    rest_m = np.broadcast_to(np.eye(4), (joints, 4, 4)).copy()
    rest_m[:, :3, 3] = rng.normal(size=(joints, 3))
    pose = rest_m.copy()
    for j in range(joints):
        q = _random_rotations(rng, 1, 0.8)[0]
        from shapespace.core.posespace.readers import quaternion_to_matrix
        pose[j, :3, :3] = quaternion_to_matrix(q)
    rig = SkinningRig(np.eye(4), [ArmatureDeform(SkinWeights(gi, gw), [f"b{j}" for j in range(joints)], rest_m,
                                                 np.eye(4))])
    coords = rng.normal(size=(p, 3))
    sculpt = deform(coords + 0.01 * rng.normal(size=(p, 3)), rig, [pose])
    t = time.perf_counter()
    inv = invert_deformation(lambda c: deform(c, rig, [pose]), coords, sculpt)
    out["invert_s_30k"] = time.perf_counter() - t
    out["invert_residual_rel_30k"] = float(inv.residual / np.linalg.norm(np.ptp(coords, axis=0)))
    # global RBF (all vertices, one kernel) vs scipy on the same data
    flat = D.reshape(n_ex, -1)
    t = time.perf_counter()
    ours = rbf.fit_rbf(X, flat, "gaussian", 0.3, -1)
    ours_val = ours(x[None])
    out["rbf_fit_eval_s_ours"] = time.perf_counter() - t
    t = time.perf_counter()
    ref = RBFInterpolator(X, flat, kernel="gaussian", epsilon=0.3, degree=-1)(x[None])
    out["rbf_fit_eval_s_scipy"] = time.perf_counter() - t
    out["rbf_max_abs_diff_vs_scipy"] = float(np.abs(ours_val - ref).max())
    return out


# --- final-shape examples (issue #16 Build 1; helper G) ---

def _subdivide_to(ob, target):
    """Subdivide ``ob`` (Edit Mode Subdivide interpolates vertex groups) to about ``target`` vertices: every face
    twice, then the faces with the largest x once more until the count is reached."""
    import bpy
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.subdivide(number_cuts=2)
    bpy.ops.object.mode_set(mode="OBJECT")
    me = ob.data
    extra = target - len(me.vertices)
    if extra > 0:
        centres = np.empty(len(me.polygons) * 3, np.float32)
        me.polygons.foreach_get("center", centres)
        x = centres.reshape(-1, 3)[:, 0]
        chosen = np.zeros(len(x), bool)
        chosen[np.argsort(-x)[: extra // 2]] = True      # one cut adds about two vertices per quad
        import bmesh
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="DESELECT")
        bm = bmesh.from_edit_mesh(me)
        bm.faces.ensure_lookup_table()
        for f in np.flatnonzero(chosen):
            bm.faces[int(f)].select_set(True)
        bmesh.update_edit_mesh(me)
        bpy.ops.mesh.subdivide(number_cuts=1)
        bpy.ops.object.mode_set(mode="OBJECT")


def final_shape(quick=False):
    """Final-shape examples on a ~30k-vertex CesiumMan (subdivided, weights interpolated): re-invert time after a
    weight change, and the evaluated mesh at the example pose against the sculpt (issue #16 Build 1)."""
    import bpy

    from shapespace.bridge import meshes, posespace
    from shapespace.bridge.posespace import finalshape
    ob, arm, _, _, _ = _rig(*REGIONS["cesium_arm"][:2])
    arm.animation_data.action = None
    bpy.context.view_layer.objects.active = ob
    _subdivide_to(ob, 30000)
    p = len(ob.data.vertices)
    bone = REGIONS["cesium_arm"][2][1]
    pb = arm.pose.bones[bone]
    pb.rotation_mode = "QUATERNION"
    pb.rotation_quaternion = (0.85, 0.35, 0.3, 0.2)
    bpy.context.view_layer.update()
    name = posespace.add_example(ob)
    copy = ob.shapespace_psd.examples[name].sculpt
    co = meshes.vertex_positions(copy.data).astype(np.float64)
    size = float(np.linalg.norm(np.ptp(co, axis=0)))
    rng = np.random.default_rng(7)
    co += 0.01 * size * np.sin(co @ rng.normal(size=(3, 3)) * 6.0 / size)     # smooth, every vertex moves
    wanted = meshes.to_local(ob, meshes.to_world(copy, co))
    posespace.apply_example(ob, name, wanted)
    bpy.data.objects.remove(copy)
    # re-weight: the strongest group of every vertex shared by two bones loses 30 % (normalised by the modifier)
    shared_v = [v.index for v in ob.data.vertices if len(v.groups) > 1][:: 3]
    for v in shared_v:
        g = max(ob.data.vertices[v].groups, key=lambda g: g.weight)
        ob.vertex_groups[g.group].add([v], g.weight * 0.7, "REPLACE")
    t = time.perf_counter()
    stale = finalshape.stale_examples(ob)
    t_stale = time.perf_counter() - t
    assert [s[0] for s in stale] == [name], stale
    pb.rotation_quaternion = (1, 0, 0, 0)
    bpy.context.view_layer.update()
    times = []
    for _ in range(1 if quick else 3):          # re-inverting is idempotent: the median of a few runs
        t = time.perf_counter()
        finalshape.reinvert_example(ob, name)
        times.append(time.perf_counter() - t)
    t_reinvert = float(np.median(times))
    pb.rotation_quaternion = (0.85, 0.35, 0.3, 0.2)
    for kb in ob.data.shape_keys.key_blocks[1:]:
        kb.value = 1.0 if kb.name == name else 0.0
    bpy.context.view_layer.update()
    got = meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)
    return {"reinvert_s_30k": t_reinvert, "reinvert_vertices_30k": p, "stale_check_s_30k": t_stale,
            "stale_roundtrip_err_rel": float(np.abs(got - wanted).max() / size)}


def _cesium_30k(n_examples=30, seed=3):
    """CesiumMan subdivided to ~30k vertices (bmesh interpolates the deform weights), its walk kept for the
    frames, and ``n_examples`` examples at random poses of every bone with smooth rest-space correctives."""
    import bmesh
    import bpy

    from shapespace.bridge import posespace
    ob, arm, _, _, _ = _rig(*REGIONS["cesium_arm"][:2])
    bm = bmesh.new()
    bm.from_mesh(ob.data)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=2, use_grid_fill=True)
    bm.edges.ensure_lookup_table()             # top up to 30,000 vertices: one more cut on some edges
    more = 30000 - len(bm.verts)
    if more > 0:
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:more], cuts=1, use_grid_fill=True)
    bm.to_mesh(ob.data)
    bm.free()
    ob.data.update()
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    action = arm.animation_data.action
    arm.animation_data.action = None
    rng = np.random.default_rng(seed)
    bones = list(arm.pose.bones)
    for pb in bones:
        pb.rotation_mode = "QUATERNION"
    co = np.empty(3 * len(ob.data.vertices), dtype=np.float32)
    ob.data.vertices.foreach_get("co", co)
    rest = co.reshape(-1, 3).astype(np.float64)
    size = float(np.linalg.norm(np.ptp(rest, axis=0)))
    centre = rest.mean(axis=0)
    for k in range(n_examples):
        for pb in bones:
            pb.rotation_quaternion = _random_rotations(rng, 1, 0.5)[0]
        bpy.context.view_layer.update()
        name = posespace.add_example(ob, make_sculpt_copy=False)
        kb = ob.data.shape_keys.key_blocks[name]
        if k == 0:
            proj = None
        x = posespace.read_pose(ob)
        if proj is None:                                   # a corrective that is a smooth function of the pose
            proj = rng.normal(size=(3, x.size)) / np.sqrt(x.size)
        disp = 0.01 * size * np.sin((rest - centre) / size * 6.0 + proj @ x)
        kb.points.foreach_set("co", (rest + disp).astype(np.float32).ravel())
    ob.data.update()
    arm.animation_data.action = action
    return ob, arm


def _median_ms(fn, frames):
    """Median milliseconds of ``fn(frame)`` over ``frames`` (the minimum is kept in ``_median_ms.last_min``)."""
    times = []
    for f in frames:
        t = time.perf_counter()
        fn(f)
        times.append(time.perf_counter() - t)
    _median_ms.last_min = float(np.min(times) * 1e3)
    return float(np.median(times) * 1e3)


def live30k(quick=False, verbose=False) -> dict:
    """Update Correctives and a live-preview frame change on a 30k-vertex skinned character, end to end:
    the operator (or the frame-change handler) plus Blender's write and depsgraph evaluation."""
    import os

    import bpy

    from shapespace.ui import posespace_preview
    ob, arm = _cesium_30k()
    st = ob.shapespace_psd
    scene = bpy.context.scene
    frames = list(range(2, 22 if quick else 50))
    out = {"live_vertices_30k": float(len(ob.data.vertices)), "live_examples_30k": float(len(st.examples)),
           "live_load_avg_1min": os.getloadavg()[0]}
    for method, distance in (("psd", "SKIN"), ("sbe", "SKIN"), ("wpsd", "SKIN"), ("wpsd_blend", "BLEND"),
                             ("wpsd_pairs", "PAIRS")):
        st.method = method.split("_")[0].upper()
        st.wpsd_distance = distance
        st.live_preview = False
        scene.frame_set(1)
        t = time.perf_counter()
        assert bpy.ops.shapespace.psd_update() == {"FINISHED"}
        out[f"update_train_s_30k_{method}"] = time.perf_counter() - t

        def update(f):
            scene.frame_set(f)      # pose change (not timed below: the operator and the evaluation are)
            t0 = time.perf_counter()
            bpy.ops.shapespace.psd_update()
            bpy.context.view_layer.update()
            return time.perf_counter() - t0
        times = [update(f) for f in frames]
        out[f"update_ms_30k_{method}"] = float(np.median(times) * 1e3)
        out[f"update_ms_30k_{method}_min"] = float(np.min(times) * 1e3)
        # live preview: a frame change runs the handler, which writes; the frame change evaluates
        posespace_preview.CACHE.clear()
        st.live_preview = True
        scene.frame_set(1)                   # trains the preview's model
        base = _median_ms(lambda f: (scene.frame_set(f), bpy.context.view_layer.update()), frames)
        out[f"preview_frame_ms_30k_{method}"] = base
        out[f"preview_frame_ms_30k_{method}_min"] = _median_ms.last_min
        st.live_preview = False
        out[f"frame_ms_30k_{method}_without_preview"] = _median_ms(
            lambda f: (scene.frame_set(f), bpy.context.view_layer.update()), frames)
        if verbose:
            print(method, {k: v for k, v in out.items() if method in k}, flush=True)
    out["live_load_avg_1min_end"] = os.getloadavg()[0]
    return out


def postdeform(quick=False):
    """Post-deformation correctives (issue #16 Build 3) on CesiumMan's arm: the evaluated mesh at the example
    pose against the sculpt, and baked playback with the add-on unregistered against the live preview."""
    import os
    import tempfile

    import bpy

    import package
    from shapespace.bridge import meshes, posespace
    from shapespace.bridge.posespace import postdeform as pd
    pkg = package.load()
    ob, arm, _, _, _ = _rig(*REGIONS["cesium_arm"][:2])
    arm.animation_data.action = None
    bpy.context.view_layer.objects.active = ob
    bone = REGIONS["cesium_arm"][2][1]
    pb = arm.pose.bones[bone]
    pb.rotation_mode = "QUATERNION"
    poses = ((0.85, 0.35, 0.3, 0.2), (0.9, -0.3, 0.1, 0.2))
    st = ob.shapespace_psd
    wanted = []
    for k, q in enumerate(poses):
        pb.rotation_quaternion = q
        bpy.context.view_layer.update()
        name = posespace.add_example(ob)
        copy = st.examples[name].sculpt
        co = meshes.vertex_positions(copy.data).astype(np.float64)
        size = float(np.linalg.norm(np.ptp(co, axis=0)))
        rng = np.random.default_rng(11 + k)
        co += 0.01 * size * rng.normal(size=co.shape) * (rng.random(len(co)) < 0.2)[:, None]
        wanted.append(meshes.to_local(ob, meshes.to_world(copy, co)))
        pd.apply_post_deform(ob, name, wanted[-1])
        bpy.data.objects.remove(copy)
    errs = []
    for k, q in enumerate(poses):
        pb.rotation_quaternion = q
        bpy.context.view_layer.update()
        posespace.preview(ob)
        got = meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)
        errs.append(float(np.abs(got - wanted[k]).max() / size))
    scene = bpy.context.scene
    for f, q in ((1, (1, 0, 0, 0)), (10, poses[0]), (20, poses[1])):
        pb.rotation_quaternion = q
        pb.keyframe_insert("rotation_quaternion", frame=f)
    frames = (4, 10, 13, 17, 20)
    live = {}
    for f in frames:
        scene.frame_set(f)
        posespace.preview(ob)
        bpy.context.view_layer.update()
        live[f] = meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)
    posespace.bake_weights(ob, scene, 1, 20)
    mesh_name = ob.name
    path = os.path.join(tempfile.mkdtemp(prefix="ss-bench-pd-"), "postdeform.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    pkg.unregister()
    try:
        bpy.ops.wm.open_mainfile(filepath=path)
        ob = bpy.data.objects[mesh_name]
        play = 0.0
        for f in frames:
            bpy.context.scene.frame_set(f)
            got = meshes.evaluated_positions(ob, bpy.context.evaluated_depsgraph_get()).astype(np.float64)
            play = max(play, float(np.abs(got - live[f]).max() / size))
    finally:
        pkg.register()
    return {"postdeform_roundtrip_err_rel": max(errs), "postdeform_playback_err_rel": play}


def run(quick=False, plot_path=None) -> dict:
    import package
    pkg = package.load()
    pkg.register()
    try:
        metrics, curves = quality(quick)
        metrics.update(roundtrip())
        metrics.update(speed(quick))
        metrics.update(live30k(quick))
        metrics.update(final_shape(quick))
        metrics.update(postdeform(quick))
    finally:
        pkg.unregister()
    if plot_path:
        plot(curves, plot_path)
    return metrics
