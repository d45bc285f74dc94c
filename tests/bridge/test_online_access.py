"""Live capture beyond this computer follows Blender's online access, including its command-line override
(``--offline-mode`` / ``--online-mode`` overrule the preference: ``bpy.app.online_access_override``)."""
import os

import pytest

from blender_support import bpy, import_file
from live_support import configure
from shapespace.bridge.live import session
from support import ASSETS

BLEND = os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend")


def _fbhead():
    import_file(BLEND)
    ob = bpy.data.objects["FBHead"]
    bpy.context.view_layer.objects.active = ob
    return ob


def test_the_preference_decides_when_blender_was_started_without_an_override(registered):
    """Real Blender: the bpy module runs without --offline-mode/--online-mode, so the preference decides."""
    assert not bpy.app.online_access_override
    ob = _fbhead()
    configure(ob)
    bpy.context.scene.shapespace_live.address = "0.0.0.0"
    bpy.context.preferences.system.use_online_access = False
    assert not bpy.app.online_access
    with pytest.raises(RuntimeError, match="Allow Online Access"):
        bpy.ops.shapespace.live_start()
    assert session.RUNTIME.session is None
    bpy.context.preferences.system.use_online_access = True
    assert bpy.app.online_access
    try:
        assert bpy.ops.shapespace.live_start() == {"FINISHED"}
        assert session.RUNTIME.session is not None
    finally:
        session.stop()


@pytest.mark.parametrize("address", ["0.0.0.0", "192.168.1.20", "::"])
def test_started_with_offline_mode_the_message_names_the_option_not_the_preference(address):
    """Started with --offline-mode (online_access False, override True) the preference cannot allow it:
    the refusal says to restart without the option."""
    why = session.network_refusal(address, online_access=False, override=True)
    assert why is not None and "--offline-mode" in why and "Preferences" not in why
    # without the override, the preference is the way out
    why = session.network_refusal(address, online_access=False, override=False)
    assert why is not None and "Allow Online Access" in why and "--offline-mode" not in why


@pytest.mark.parametrize("override", [False, True])
def test_online_access_allows_and_loopback_never_needs_it(override):
    """--online-mode (online_access True, override True) allows it whatever the preference; 127.0.0.1 and
    localhost are always allowed (nothing leaves this computer)."""
    assert session.network_refusal("0.0.0.0", online_access=True, override=override) is None
    for address in ("127.0.0.1", "localhost", "::1"):
        assert session.network_refusal(address, online_access=False, override=override) is None
