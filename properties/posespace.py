"""Stored per object: pose-space readers, examples and driven targets (``Object.shapespace_psd``).

An example's ``pose``, ``pseudo_pose`` and ``target_values`` are versioned JSON strings, read and written only
through ``bridge.posespace.stored`` (schemas there; 0.1.0 files held bare JSON lists and still load).
"""
import bpy


class SHAPESPACE_PG_reader(bpy.types.PropertyGroup):
    """One control of the pose space"""

    kind: bpy.props.EnumProperty(
        name="Reads",
        items=[("ROTATION", "Rotation", "The bone's local rotation (q and −q are the same pose)"),
               ("SWING", "Swing", "Where the bone points; ignores its roll"),
               ("TWIST", "Twist", "The bone's roll about its own axis"),
               ("LOCATION", "Location", "The bone's local location"),
               ("PROPERTY", "Property", "A custom property of the armature (an 'adjective' such as exertion)"),
               ("SHAPE_KEY", "Shape Key", "A shape-key value (weighted pose space editing)")],
        default="ROTATION")
    source: bpy.props.StringProperty(name="Source", description="Bone, property path or shape key")
    scale: bpy.props.FloatProperty(name="Scale", default=1.0, min=1e-6, description="Weight of this control")


class SHAPESPACE_PG_target(bpy.types.PropertyGroup):
    """A value driven from pose space (a shape-key value, bone channel or custom property; thesis 7.3.3)"""

    owner: bpy.props.PointerProperty(name="Owner", type=bpy.types.ID,
                                     description="Datablock that holds the value (object, armature, shape keys)")
    data_path: bpy.props.StringProperty(name="Data Path", description='e.g. pose.bones["Arm"].scale')
    index: bpy.props.IntProperty(name="Index", default=-1, min=-1, description="Array index, −1 for a scalar")


class SHAPESPACE_PG_example(bpy.types.PropertyGroup):
    """A sculpted corrective at a pose (its shape key has the same name)"""

    pose: bpy.props.StringProperty(name="Pose", options={"HIDDEN"})
    pseudo_pose: bpy.props.StringProperty(
        name="Pseudo Pose", options={"HIDDEN"},
        description="Where in pose space the sculpt is interpolated, when moved (Shape-by-Example)")
    mute: bpy.props.BoolProperty(name="Mute", description="Leave this example out of the interpolation")
    flags: bpy.props.StringProperty(name="Flags", description="Duplicate, conflicting or outlier example")
    sculpt: bpy.props.PointerProperty(name="Sculpt", type=bpy.types.Object,
                                      description="Posed copy to sculpt the wanted shape on")
    target_values: bpy.props.StringProperty(name="Target Values", options={"HIDDEN"},
                                            description="Values of the driven targets at this example")
    post_deform: bpy.props.BoolProperty(
        name="Post-Deformation", options={"HIDDEN"},
        description="Applied after the armature, in a frame of the deformed surface (generated Geometry Nodes "
                    "modifier); its shape key is muted and drives the weight")
    final_shape: bpy.props.StringProperty(
        name="Final Shape", options={"HIDDEN"},
        description="The sculpted posed shape, the rig pose and the inputs the corrective was inverted from "
                    "(versioned JSON; empty for examples made by ShapeSpace 0.1.0)")


class SHAPESPACE_PG_psd(bpy.types.PropertyGroup):
    armature: bpy.props.PointerProperty(
        name="Armature", type=bpy.types.Object,
        description="Armature whose pose drives the correctives (default: the Armature modifier's)")
    # (no poll function on this pointer: bpy 4.2 crashes at exit with one registered; armature_of checks)
    method: bpy.props.EnumProperty(
        name="Method",
        items=[("PSD", "PSD", "Pose space deformation: Gaussian RBF per vertex"),
               ("SBE", "Shape by Example", "One set of weights from linear + radial cardinal interpolation"),
               ("WPSD", "Weighted PSD", "Per-vertex pose distance weighted by skinning weights")],
        default="SBE")
    wpsd_distance: bpy.props.EnumProperty(
        name="Distance",
        items=[("SKIN", "Skin Weighted", "Weighted PSD as published: each vertex sees its own joints' part of the "
                "pose"),
               ("BLEND", "Blended", "Per region, by leave-one-out cross validation over the examples: the "
                "skin-weighted distance, a blend of it with the whole-pose distance (correctives that depend on "
                "joints a vertex is not skinned to) or the bone-pair distance"),
               ("PAIRS", "Bone Pairs", "Each vertex sees how its bones turn relative to each other (what skinning "
                "artefacts grow with), plus a quarter of each bone's own rotation: fewer examples for joint "
                "correctives")],
        default="BLEND",
        description="Weighted PSD's pose distance (pose spaces made before ShapeSpace 0.2.0 keep Skin Weighted)")
    readers: bpy.props.CollectionProperty(type=SHAPESPACE_PG_reader)
    active_reader: bpy.props.IntProperty(name="Active Reader")
    examples: bpy.props.CollectionProperty(type=SHAPESPACE_PG_example)
    targets: bpy.props.CollectionProperty(type=SHAPESPACE_PG_target)
    active_example: bpy.props.IntProperty(name="Active Example")
    live_preview: bpy.props.BoolProperty(
        name="Live Preview", description="Update the correctives while posing and scrubbing")
    revision: bpy.props.IntProperty(options={"HIDDEN"}, description="Bumped when examples change")
    preview_message: bpy.props.StringProperty(
        name="Live Preview Stopped", options={"HIDDEN"},
        description="Why Live Preview last stopped for this mesh (cleared when it runs again)")
