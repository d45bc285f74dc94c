"""tools/build.py fetches missing wheels on a clean clone: its pip command must mean what it says.

The command is checked with pip's own option parser (an independent reference), for a platform wheel and
for a pure-Python one; a clean-clone CI run once failed because ``-d`` had lost its directory argument.
"""
import importlib.util
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _build_module():
    spec = importlib.util.spec_from_file_location("shapespace_build_tool", os.path.join(ROOT, "tools", "build.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _parse_with_pip(cmd):
    commands = pytest.importorskip("pip._internal.commands")
    assert cmd[1:4] == ["-m", "pip", "download"]
    download = commands.create_command("download")
    return download.parse_args(cmd[4:])


@pytest.mark.parametrize("wheel, python, platform", [
    ("scipy-1.15.3-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl", "311", "manylinux_2_17_x86_64"),
    ("scipy-1.15.3-cp313-cp313-win_amd64.whl", "313", "win_amd64"),
    ("scipy-1.15.3-cp313-cp313-macosx_12_0_arm64.whl", "313", "macosx_12_0_arm64"),
    ("scipy-1.17.1-cp311-cp311-win_arm64.whl", "311", "win_arm64"),
    ("scipy-1.17.1-cp313-cp313-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl", "313", "manylinux_2_28_x86_64"),
])
def test_platform_wheel_download_command(tmp_path, wheel, python, platform):
    cmd = _build_module().pip_download_command(wheel, str(tmp_path))
    options, args = _parse_with_pip(cmd)
    assert args == ["scipy==" + wheel.split("-")[1]]
    assert os.path.samefile(options.download_dir, tmp_path)
    assert options.platforms == [platform]
    assert "".join(str(p) for p in options.python_version) == python
    assert options.implementation == "cp"


def test_pure_python_wheel_download_command(tmp_path):
    cmd = _build_module().pip_download_command("python_osc-1.10.2-py3-none-any.whl", str(tmp_path))
    options, args = _parse_with_pip(cmd)
    assert args == ["python-osc==1.10.2"] or args == ["python_osc==1.10.2"]
    assert os.path.samefile(options.download_dir, tmp_path)
    assert not options.platforms


def test_unparseable_wheel_name_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="cannot parse wheel name"):
        _build_module().pip_download_command("not-a-wheel.zip", str(tmp_path))
