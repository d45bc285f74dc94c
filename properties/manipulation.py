"""Stored per object: pins and pin-and-drag settings (``Object.shapespace``)."""
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
    mirror_of: bpy.props.IntProperty(
        name="Mirror Pin", default=-1, min=-1,
        description="Index of this pin's mirror pin (itself for a pin on the centre line, -1 for none); "
                    "with Symmetric on, the two move together")


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
    symmetric: bpy.props.BoolProperty(
        name="Symmetric",
        description="A new pin also pins its mirror point (through the mesh's stored mirror map) and a dragged "
                    "pin's mirror pin follows to the mirror image of its target")
