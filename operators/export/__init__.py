"""Operators: export for engines (glTF, FBX, Alembic) with drivers and pose-space correctives baked."""
from .export_for_engines import SHAPESPACE_OT_export_for_engines

classes = (SHAPESPACE_OT_export_for_engines,)
