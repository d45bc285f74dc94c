"""Stored per target object: the Transfer Shapes settings (``Object.shapespace_authoring``).

No ``update=``/``poll=`` callbacks (bpy 4.2 crashes at exit with them).  The landmark pairs are a versioned
JSON blob on the object (``Object["shapespace_landmarks"]``, :mod:`bridge.authoring`), so the command line
reads them without the add-on's classes.
"""
import bpy

NAMING = [("source", "Source Names", "Keep the source rig's key names"),
          ("arkit", "ARKit camelCase", "eyeBlinkLeft, jawOpen, …"),
          ("suffix", "_L / _R", "eyeBlink_L, jawOpen, …"),
          ("pascal", "PascalCase", "EyeBlinkLeft, JawOpen, … (Live Link Face)")]
EXISTING = [("refuse", "Refuse", "Stop, naming the target's keys that already have one of the new names"),
            ("skip", "Skip Existing", "Keep the target's keys; transfer only shapes it does not have yet"),
            ("overwrite", "Overwrite", "Replace the target's keys of the same names")]
PARTS = [("move", "Move as Rigged", "Separate parts move as an artist would rig them: lashes, brows and the mouth "
          "cavity follow the skin under them, lower teeth and tongue the jaw, upper teeth the skull, eyes turn for "
          "the eyeLook shapes; parts the source has and moves take its motion; the report lists each part"),
         ("keep", "Keep Still", "Separate parts of this mesh with no counterpart on the source (eyes, teeth) "
          "stay still in every new shape; the report names them"),
         ("refuse", "Refuse", "Stop when a separate part of this mesh has no counterpart on the source")]


class SHAPESPACE_PG_transfer_example(bpy.types.PropertyGroup):
    """A shape key of the target given as an example of the source rig's shapes (Transfer Shapes ▸ Examples)."""

    key: bpy.props.StringProperty(name="Shape Key", description="The target's shape key that is the example")
    weights: bpy.props.StringProperty(
        name="Weights", description="The source shapes this example shows, as name=weight pairs (jawOpen=1, "
                                    "mouthClose=0.5); empty: the source shape of the key's name at 1")


class SHAPESPACE_PG_authoring(bpy.types.PropertyGroup):
    """Transfer Shapes settings of a target mesh (what the Rig ▸ Transfer Shapes panel edits)."""

    source: bpy.props.PointerProperty(name="Source Rig", type=bpy.types.Object,
                                      description="The mesh whose shape keys are transferred onto this one")
    naming: bpy.props.EnumProperty(name="Naming", items=NAMING, default="source",
                                   description="Naming convention of the transferred keys")
    existing: bpy.props.EnumProperty(name="Existing Keys", items=EXISTING, default="refuse",
                                     description="What to do when this mesh already has keys of the new names")
    unmatched_parts: bpy.props.EnumProperty(name="Unmatched Parts", items=PARTS, default="move",
                                            description="Separate parts of this mesh the source rig does not have")
    parts_collection: bpy.props.PointerProperty(
        name="Part Objects", type=bpy.types.Collection,
        description="Meshes of this collection (eyes, teeth, tongue as objects of their own) are transferred with "
                    "this mesh as its parts and get shape keys of the same names")
    examples: bpy.props.CollectionProperty(
        name="Examples", type=SHAPESPACE_PG_transfer_example,
        description="Shape keys of this mesh that show how some source shapes should look on it: every transferred "
                    "key is refined so they are reproduced, and they are kept as they are")
    active_example: bpy.props.IntProperty(name="Active Example", min=0)
