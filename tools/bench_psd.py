"""Pose-space corrective benchmark (issue #4): quality vs examples, inversion round trip, speed."""
from __future__ import annotations

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


def quality(quick):
    from shapespace.core.posespace.inversion import invert_deformation
    from shapespace.core.posespace.psd import train_psd
    out = {}
    curves = {}
    n_test = 100
    for name in [r for r in REGIONS if shared_data(REGIONS[r][0], f"the {r} region")]:
        region = Region(name)
        rng = np.random.default_rng(11)
        nj = len(region.joints)
        # realistic pose space: every joint bends about its own axis, independently
        train_q = [_bends(rng, nj, 1.3) for _ in range(max(KS))]
        test_q = [_bends(rng, nj, 1.3) for _ in range(n_test)]
        for ref in ("dqs", "bulge"):
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
            tag = f"{name}" if ref == "dqs" else f"{name}_bulge"
            for method in ("lbs", "psd", "sbe", "wpsd"):
                for K in KS:
                    if method == "lbs" and K != KS[0]:
                        out[f"err_mean_lbs_k{K}_{tag}"] = out[f"err_mean_lbs_k{KS[0]}_{tag}"]
                        out[f"err_max_lbs_k{K}_{tag}"] = out[f"err_max_lbs_k{KS[0]}_{tag}"]
                        continue
                    model = None
                    if method != "lbs":
                        kw = {}
                        if method == "wpsd":
                            kw = dict(vertex_groups=region.wpsd_groups, vertex_weights=region.wpsd_weights,
                                      group_columns=region.columns)
                        model = train_psd(train_X[:K], train_D[:K], method, **kw)
                    errs = []
                    for x, pose, want in tests:
                        coords = region.rest if model is None else region.rest + model.evaluate(x)
                        got = region.deform(coords, pose, False)
                        errs.append(np.linalg.norm(got - want, axis=1)[region.verts] / region.size)
                    errs = np.array(errs)
                    out[f"err_mean_{method}_k{K}_{tag}"] = float(errs.mean())
                    out[f"err_max_{method}_k{K}_{tag}"] = float(errs.max())
            psd32 = out[f"err_mean_psd_k{max(KS)}_{tag}"]
            reach = [K for K in KS if out[f"err_mean_wpsd_k{K}_{tag}"] <= psd32]
            out[f"wpsd_examples_for_psd32_{tag}"] = float(min(reach)) if reach else float("inf")
            curves[tag] = {m: [out[f"err_mean_{m}_k{K}_{tag}"] for K in KS] for m in ("lbs", "psd", "sbe", "wpsd")}
    return out, curves


def plot(curves, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(curves), figsize=(4.2 * len(curves), 3.6), squeeze=False)
    for ax, (tag, c) in zip(axes[0], curves.items()):
        for m, style in (("lbs", "k--"), ("psd", "o-"), ("sbe", "s-"), ("wpsd", "^-")):
            ax.plot(KS, c[m], style, label=m.upper())
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
    exact = model.evaluate(x)
    fast = model.evaluate_fast(x)
    t = time.perf_counter()
    for _ in range(reps * 5):
        model.evaluate_fast(x)
    out["wpsd_eval_ms_30k_n30"] = (time.perf_counter() - t) / (reps * 5) * 1e3
    out["wpsd_eval_fast_rel_diff"] = float(np.abs(fast - exact).max() / np.abs(exact).max())
    t = time.perf_counter()
    for _ in range(reps):
        model.evaluate(x)
    out["wpsd_eval_ms_30k_n30_float64"] = (time.perf_counter() - t) / reps * 1e3
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


def run(quick=False, plot_path=None) -> dict:
    import package
    pkg = package.load()
    pkg.register()
    try:
        metrics, curves = quality(quick)
        metrics.update(roundtrip())
        metrics.update(speed(quick))
    finally:
        pkg.unregister()
    if plot_path:
        plot(curves, plot_path)
    return metrics
