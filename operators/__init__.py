"""Operators, one per file, grouped by capability: poll → bridge → core → bridge → report."""
import bpy

from . import authoring, export, facespace, live, manipulation, posespace, retarget, rig

classes = (*rig.classes, *manipulation.classes, *posespace.classes, *retarget.classes, *facespace.classes,
           *live.classes, *export.classes, *authoring.classes)

register, unregister = bpy.utils.register_classes_factory(classes)
