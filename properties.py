"""Data ShapeSpace stores in the .blend: pins and direct-manipulation settings, per object."""
import bpy


class SHAPESPACE_PG_pin(bpy.types.PropertyGroup):
    """A point on the surface (1–3 vertices with barycentric weights) and where it should go"""

    vertices: bpy.props.IntVectorProperty(name="Vertices", size=3, min=0)
    weights: bpy.props.FloatVectorProperty(name="Weights", size=3, default=(1.0, 0.0, 0.0))
    target: bpy.props.FloatVectorProperty(
        name="Target", size=3, subtype="XYZ",
        description="Where the pin should be, in the mesh's shape-key (undeformed object) space")
    stationary: bpy.props.BoolProperty(
        name="Stationary", description="Keep this point where it was when it was pinned")


class SHAPESPACE_PG_settings(bpy.types.PropertyGroup):
    pins: bpy.props.CollectionProperty(type=SHAPESPACE_PG_pin)
    active_pin: bpy.props.IntProperty(name="Active Pin", default=0)
    mode: bpy.props.EnumProperty(
        name="Mode",
        items=[("SLIDERS", "Sliders", "Animate with the shape-key sliders only"),
               ("DIRECT", "Direct", "Drag pins; sliders follow (thesis Eq. 4.5)"),
               ("LEARNED", "Learned", "Drag pins with a prior learned from earlier animation (thesis 4.3)")],
        default="DIRECT")
    alpha: bpy.props.FloatProperty(
        name="Stay Near", default=0.1, min=0.0, soft_max=10.0,
        description="Weight of staying near the sliders before the drag (α)")
    mu: bpy.props.FloatProperty(
        name="Stay Small", default=0.001, min=0.0, soft_max=1.0,
        description="Weight of keeping all sliders small (μ)")
    prior_action: bpy.props.PointerProperty(
        name="Prior Action", type=bpy.types.Action,
        description="Animation of this mesh's shape keys to learn the prior from")
    prior_start: bpy.props.IntProperty(name="Start", default=1, description="First training frame")
    prior_end: bpy.props.IntProperty(name="End", default=250, description="Last training frame")
    prior_form: bpy.props.EnumProperty(
        name="Prior",
        items=[("COVARIANCE", "Covariance", "Regularised covariance in slider space: prefers the "
                "training data's directions and still reaches any expression (default)"),
               ("PCA", "PCA", "Thesis Eq. 4.8: PCA coefficients bounded by 3 standard deviations")],
        default="COVARIANCE")
    snap: bpy.props.BoolProperty(
        name="Mode Snapping", description="Pull toward nearby training expressions (thesis Eq. 4.9)")


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
    readers: bpy.props.CollectionProperty(type=SHAPESPACE_PG_reader)
    active_reader: bpy.props.IntProperty(name="Active Reader")
    examples: bpy.props.CollectionProperty(type=SHAPESPACE_PG_example)
    targets: bpy.props.CollectionProperty(type=SHAPESPACE_PG_target)
    active_example: bpy.props.IntProperty(name="Active Example")
    live_preview: bpy.props.BoolProperty(
        name="Live Preview", description="Update the correctives while posing and scrubbing")
    revision: bpy.props.IntProperty(options={"HIDDEN"}, description="Bumped when examples change")


RETARGET_METHODS = [
    ("copy", "Copy", "Copy the mapped channels (corresponding parameterisation)"),
    ("learned", "Learned", "Linear expression cloning learnt from the target posed at key poses"),
    ("perframe", "Per Frame", "Fit the sliders to the source motion frame by frame"),
    ("spacetime", "Space-Time", "Match the motion's velocities (keeps its shape at slider limits)")]
KEY_SHAPES = [("BEZIER", "Smooth", "Bézier keys with aligned handles along the curve's slope (fewest keys)"),
              ("LINEAR", "Linear", "Linear keys (a subset of the frames, straight segments)")]


class SHAPESPACE_PG_retarget(bpy.types.PropertyGroup):
    """Retarget settings of a target rig (what the Retarget panel edits)."""

    source_kind: bpy.props.EnumProperty(
        name="Source", items=[("CSV", "Capture File", "A Live Link Face CSV recording"),
                              ("ACTION", "Action", "An action animating shape keys (any naming convention)"),
                              ("MESH", "Mesh Performance", "An animated mesh: shape keys, Mesh Cache, any modifier")],
        default="CSV")
    csv_path: bpy.props.StringProperty(name="CSV File", subtype="FILE_PATH")
    action: bpy.props.PointerProperty(name="Action", type=bpy.types.Action)
    source_object: bpy.props.PointerProperty(name="Mesh", type=bpy.types.Object)
    key_pose_action: bpy.props.PointerProperty(
        name="Key Poses", type=bpy.types.Action,
        description="Learned method: an action keying this rig's shape keys at the key-pose frames")
    method: bpy.props.EnumProperty(name="Method", items=RETARGET_METHODS, default="spacetime")
    key_tolerance: bpy.props.FloatProperty(name="Key Tolerance", default=0.01, min=0.0, max=0.1,
                                           description="Keep the fewest keys within this slider error (0: all)")
    key_shape: bpy.props.EnumProperty(name="Key Shape", items=KEY_SHAPES, default="BEZIER")


class SHAPESPACE_PG_flagged_frame(bpy.types.PropertyGroup):
    """A frame the face prior finds implausible."""

    frame: bpy.props.IntProperty(name="Frame")
    reason: bpy.props.StringProperty(name="Reason")


class SHAPESPACE_PG_face(bpy.types.PropertyGroup):
    """Face-space tool state of a rig (what the Face Space panel shows)."""

    implausible: bpy.props.CollectionProperty(type=SHAPESPACE_PG_flagged_frame)
    active_implausible: bpy.props.IntProperty(name="Active Frame")
    confidence: bpy.props.FloatProperty(name="Pose-Space Variance", default=-1.0,
                                        description="Last computed GP variance at the pose (−1: not computed)")
    gap_path: bpy.props.StringProperty(name="Curve", description='Data path, e.g. key_blocks["jawOpen"].value')
    gap_index: bpy.props.IntProperty(name="Index", min=0)
    gap_start: bpy.props.IntProperty(name="From", default=1)
    gap_end: bpy.props.IntProperty(name="To", default=10)


classes = (SHAPESPACE_PG_pin, SHAPESPACE_PG_settings, SHAPESPACE_PG_reader, SHAPESPACE_PG_target,
           SHAPESPACE_PG_example, SHAPESPACE_PG_psd, SHAPESPACE_PG_retarget,
           SHAPESPACE_PG_flagged_frame, SHAPESPACE_PG_face)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.shapespace = bpy.props.PointerProperty(type=SHAPESPACE_PG_settings)
    bpy.types.Object.shapespace_psd = bpy.props.PointerProperty(type=SHAPESPACE_PG_psd)
    bpy.types.Object.shapespace_retarget = bpy.props.PointerProperty(type=SHAPESPACE_PG_retarget)
    bpy.types.Object.shapespace_face = bpy.props.PointerProperty(type=SHAPESPACE_PG_face)


def unregister():
    del bpy.types.Object.shapespace_face
    del bpy.types.Object.shapespace_retarget
    del bpy.types.Object.shapespace_psd
    del bpy.types.Object.shapespace
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
