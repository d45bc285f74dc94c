"""Viewport-only modules: the pin overlay, the pin workspace tool and the pose-space live preview handlers."""
from . import overlay, pin_tool, posespace_preview

_modules = (overlay, pin_tool, posespace_preview)


def register():
    for module in _modules:
        module.register()


def unregister():
    for module in reversed(_modules):
        module.unregister()
