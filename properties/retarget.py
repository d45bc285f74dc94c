"""Stored per object: retarget settings and the last result (``Object.shapespace_retarget``)."""
import bpy

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
        name="Source", items=[("CSV", "Capture File", "A capture recording: Live Link Face CSV, Face Cap TXT, "
                                                      "iFacialMocap, Audio2Face JSON, MediaPipe JSON/CSV"),
                              ("ACTION", "Action", "An action animating shape keys (any naming convention)"),
                              ("MESH", "Mesh Performance", "An animated mesh: shape keys, Mesh Cache, any modifier")],
        default="CSV")
    csv_path: bpy.props.StringProperty(name="Capture File", subtype="FILE_PATH")
    action: bpy.props.PointerProperty(name="Action", type=bpy.types.Action)
    source_object: bpy.props.PointerProperty(name="Mesh", type=bpy.types.Object)
    key_pose_action: bpy.props.PointerProperty(
        name="Key Poses", type=bpy.types.Action,
        description="Learned method: an action keying this rig's shape keys at the key-pose frames")
    method: bpy.props.EnumProperty(name="Method", items=RETARGET_METHODS, default="spacetime")
    key_tolerance: bpy.props.FloatProperty(name="Key Tolerance", default=0.01, min=0.0, max=0.1,
                                           description="Keep the fewest keys within this slider error (0: all)")
    key_shape: bpy.props.EnumProperty(name="Key Shape", items=KEY_SHAPES, default="BEZIER")
    extend_scene_range: bpy.props.BoolProperty(
        name="Extend Scene Range", default=True,
        description="Widen the scene's frame range to include every frame the result keys")
    armature: bpy.props.PointerProperty(name="Armature", type=bpy.types.Object,
                                        description="The armature whose head, neck and eye bones the recording's "
                                                    "head and eye channels key (as live capture)")
    head_bone: bpy.props.StringProperty(name="Head", description="Bone that takes the head rotation")
    neck_bone: bpy.props.StringProperty(name="Neck", description="Bone that takes a share of the head rotation")
    neck_share: bpy.props.FloatProperty(name="Neck Share", default=0.3, min=0.0, max=1.0, subtype="FACTOR",
                                        description="Part of the head rotation the neck bone takes")
    calibrate: bpy.props.BoolProperty(
        name="Calibrate", default=False,
        description="Make the head and eye pose at the Rest Frame the rest pose (as live capture's Calibrate)")
    rest_frame: bpy.props.IntProperty(name="Rest Frame", default=1,
                                      description="Scene frame whose head and eye pose becomes the rest pose")
    eye_left_bone: bpy.props.StringProperty(name="Left Eye", description="The character's left eye bone")
    eye_right_bone: bpy.props.StringProperty(name="Right Eye", description="The character's right eye bone")
    mirror: bpy.props.BoolProperty(name="Mirror", default=False,
                                   description="Swap left and right (a mirrored, selfie-view capture)")
    target: bpy.props.EnumProperty(
        name="Onto", default="SHAPE_KEYS",
        items=[("SHAPE_KEYS", "Shape Keys", "Retarget onto this mesh's shape-key sliders"),
               ("CONTROLS", "Rig Controls", "Retarget onto the control set stored on this face (bones, custom "
                                            "properties, sliders: Rig ▸ Controls), keyed on their actions")])
    rig_key_tolerance: bpy.props.FloatProperty(
        name="Key Tolerance", default=0.0, min=0.0, max=0.01, precision=5, subtype="DISTANCE",
        description="Rig controls: keep the fewest keys whose surface stays within this distance of every frame "
                    "(0: a key on every frame)")
