"""ShapeSpace: example-based character deformation for Blender.

Registration only; the numerics live in ``core``, Blender I/O in ``bridge``.
"""
from . import cli, operators, overlay, panels, properties, psd_preview, viewport_tool

_modules = (properties, operators, panels, overlay, viewport_tool, psd_preview, cli)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()
