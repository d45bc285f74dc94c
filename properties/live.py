"""Stored per scene: the live-capture settings (``Scene.shapespace_live``).  The running receiver's state
(status, counters) is not stored: it lives in ``bridge.live.session.RUNTIME``."""
import bpy

LIVE_SOURCES = [
    ("LLF", "Live Link Face", "Epic's Live Link Face app, 'Live Link (ARKit)' UDP packets (port 11111)"),
    ("FACECAP", "Face Cap", "Bannaflak's Face Cap, OSC over UDP (port 8080)"),
    ("IFACIALMOCAP", "iFacialMocap", "iFacialMocap's UDP text protocol (port 49983)"),
]
LIVE_METHODS = [
    ("COPY", "Copy", "Copy the channels by name (with the stored mapping's gain, offset and overrides)"),
    ("LEARNED", "Learned", "The cloning matrix learnt from the target posed at key poses of a recorded take"),
    ("SOLVE", "Solve", "Fit the target's sliders to the capture on a template ARKit head, carried across by "
     "landmarks (targets with other shapes or names)"),
    ("CONTROLS", "Solve onto Controls", "Solve the capture, played through the face's own shape keys, onto the "
     "face's stored control set (bones, drivers, properties, sliders) frame by frame within a budget"),
]
# No Python callbacks (update=, poll=) in this PropertyGroup: with them, Blender 4.2 as a Python module
# crashes at exit.  The object pointers are type-checked when the receiver starts (bridge.live.rig), and port 0
# means the source's standard port (bridge.live.session.DEFAULT_PORTS).


class SHAPESPACE_PG_live(bpy.types.PropertyGroup):
    """Live capture settings (what the Live panel edits)."""

    source: bpy.props.EnumProperty(name="Source", items=LIVE_SOURCES, default="LLF")
    address: bpy.props.StringProperty(
        name="Address", default="0.0.0.0",
        description="Network address to listen on (0.0.0.0: every interface; 127.0.0.1: this computer only)")
    port: bpy.props.IntProperty(name="Port", default=0, min=0, max=65535,
                               description="UDP port to listen on (0: the source's standard port)")
    target: bpy.props.PointerProperty(name="Target", type=bpy.types.Object,
                                      description="The mesh the capture drives (empty: the active object)")
    method: bpy.props.EnumProperty(name="Method", items=LIVE_METHODS, default="COPY")
    template: bpy.props.PointerProperty(
        name="Template", type=bpy.types.Object,
        description="Solve: an ARKit head (e.g. Face Cap's) with landmark pairs (lm_*) to the target")
    learn_csv: bpy.props.StringProperty(name="Key-Pose Take", subtype="FILE_PATH",
                                        description="Learned: the capture (CSV) the key poses were made on")
    learn_action: bpy.props.StringProperty(name="Key-Pose Take Action",
                                           description="Learned: or the action the key poses were made on")
    key_pose_action: bpy.props.PointerProperty(
        name="Key Poses", type=bpy.types.Action,
        description="Learned: an action keying the target's shape keys at the key-pose frames")
    armature: bpy.props.PointerProperty(name="Armature", type=bpy.types.Object,
                                        description="The armature whose head, neck and eye bones follow")
    head_bone: bpy.props.StringProperty(name="Head", description="Bone that takes the head rotation")
    neck_bone: bpy.props.StringProperty(name="Neck", description="Bone that takes a share of the head rotation")
    neck_share: bpy.props.FloatProperty(name="Neck Share", default=0.3, min=0.0, max=1.0, subtype="FACTOR",
                                        description="Part of the head rotation the neck bone takes")
    eye_left_bone: bpy.props.StringProperty(name="Left Eye", description="The character's left eye bone")
    eye_right_bone: bpy.props.StringProperty(name="Right Eye", description="The character's right eye bone")
    mirror: bpy.props.BoolProperty(name="Mirror", default=False,
                                   description="Swap left and right (a mirrored, selfie-view capture)")
    smoothing: bpy.props.BoolProperty(name="Smoothing", default=False,
                                      description="One-Euro filter on every channel (removes jitter at rest)")
    min_cutoff: bpy.props.FloatProperty(name="Min Cutoff", default=1.5, min=0.01, max=30.0, unit="NONE",
                                        description="One-Euro cutoff at rest in Hz (lower: smoother)")
    beta: bpy.props.FloatProperty(name="Speed", default=0.5, min=0.0, max=100.0,
                                  description="One-Euro speed coefficient (higher: less lag on fast motion)")
    take_name: bpy.props.StringProperty(name="Take", default="Take", description="Base name of recorded takes")
    clean_spacetime: bpy.props.BoolProperty(
        name="Space-Time Pass", default=False,
        description="On Stop Recording, refit the take by space-time cloning into '<take> clean'")
    clean_tolerance: bpy.props.FloatProperty(
        name="Key Tolerance", default=0.0, min=0.0, max=0.1,
        description="On Stop Recording, keep the fewest keys within this slider error in '<take> clean' (0: off)")
    active_take: bpy.props.IntProperty(name="Active Take", default=0)
