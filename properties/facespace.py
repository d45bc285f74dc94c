"""Stored per object: face-space tool state (``Object.shapespace_face``)."""
import bpy


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
