"""ShapeSpace: example-based character deformation for Blender.

Registration only; the numerics live in ``core``, Blender I/O in ``bridge``.
"""
from . import cli, operators, panels, properties, ui

_modules = (properties, operators, panels, ui, cli)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()
