"""Operators, one per file, grouped by capability: poll → bridge → core → bridge → report."""
import bpy

from . import facespace, manipulation, posespace, retarget, rig

classes = (*rig.classes, *manipulation.classes, *posespace.classes, *retarget.classes, *facespace.classes)

register, unregister = bpy.utils.register_classes_factory(classes)
