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


PART_KINDS = [("auto", "Auto", "As Find Parts and the transfer propose (the used kind and why are shown)"),
              ("follow", "Follow Skin", "Bound to the skin under it (lashes, brows, eyelines, the mouth cavity)"),
              ("jaw", "Jaw", "The jaw's rigid motion (lower teeth, lower gums, tongue)"),
              ("skull", "Skull", "Still with the skull (upper teeth and gums)"),
              ("eye", "Eye", "Turned about its centre for the eyeLook shapes"),
              ("still", "Keep Still", "Not moved by any transferred shape (a part its rig moves by itself)")]


class SHAPESPACE_PG_transfer_part(bpy.types.PropertyGroup):
    """A facial part of the target or of a part object and how transferred shapes move it (Transfer Shapes ▸
    Parts)."""

    object: bpy.props.StringProperty(name="Object", description="The mesh the part is in")
    vertex: bpy.props.IntProperty(name="Vertex", min=0, description="The part's lowest vertex index in its mesh")
    vertices: bpy.props.IntProperty(name="Vertices", min=0, description="The part's vertex count")
    size: bpy.props.FloatProperty(name="Size", min=0.0, description="The summed length of the part's edges when "
                                  "listed (a part edited since is no longer this row's)")
    kind: bpy.props.EnumProperty(name="Kind", items=PART_KINDS, default="auto",
                                 description="How transferred shapes move this part")
    used: bpy.props.StringProperty(name="Used", description="The kind the last Find Parts or transfer used")
    reason: bpy.props.StringProperty(name="Reason", description="Why that kind")
    unsure: bpy.props.BoolProperty(name="Unsure", description="The proposal is unsure of this part: check it")


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
    parts: bpy.props.CollectionProperty(
        name="Parts", type=SHAPESPACE_PG_transfer_part,
        description="The separate parts of this mesh and its Part Objects (eyes, teeth, tongue, lashes, brows, "
                    "cavity) and how transferred shapes move each; set a kind to correct the proposal")
    active_part: bpy.props.IntProperty(name="Active Part", min=0)
