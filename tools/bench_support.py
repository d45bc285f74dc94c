"""What every benchmark suite shares: where the assets are, and skipping a case whose data is missing."""
from __future__ import annotations

import os
import sys

import env

ASSETS = os.path.join(env.ROOT, "assets")
SHARED = os.environ.get("SHAPESPACE_DATA", os.path.join(os.path.dirname(env.ROOT), "shared", "data"))


def shared_data(rel: str, what: str):
    """Path of ``rel`` in the vendored ``assets/`` or in ``../shared/data``; ``None`` (with a message on
    stderr: that case is skipped) when neither has it."""
    for base in (ASSETS, SHARED):
        path = os.path.join(base, rel)
        if os.path.exists(path):
            return path
    print(f"bench: skipping {what}: {rel} is in neither assets/ nor {SHARED}", file=sys.stderr)
    return None
