"""core.paths: the one output-path check every writer uses (CLI outputs, export, point cache, coherence image)."""
import os
import stat

import pytest

from core.paths import check_output_file, same_file
from core.result import ShapeSpaceError


def _refused(path, **kwargs):
    with pytest.raises(ShapeSpaceError) as err:
        check_output_file(str(path), **kwargs)
    return err.value.code, str(err.value)


def test_a_new_file_in_an_existing_folder_is_its_absolute_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert check_output_file("sub/../a.pc2") == str(tmp_path / "a.pc2")
    assert not os.listdir(tmp_path)                                   # the writability probe leaves nothing


def test_each_refusal_names_the_path_with_its_code(tmp_path):
    (tmp_path / "dir").mkdir()
    (tmp_path / "shot.blend").write_bytes(b"BLENDER")
    assert _refused("") == ("usage", "output file: give a file name")
    assert _refused("", flag="--out") == ("usage", "--out: give a file name")
    assert _refused(tmp_path / "a.fbx", what="a gltf file", extensions=(".glb", ".gltf")) == (
        "format", f"{tmp_path / 'a.fbx'}: a gltf file must end in .glb or .gltf")
    code, message = _refused(tmp_path / "x.blend1", what="a point cache")
    assert code == "overwrite" and message == f"{tmp_path / 'x.blend1'}: is a .blend file; give a point cache"
    assert _refused(tmp_path / "dir", flag="--out") == ("not_a_file", f"--out {tmp_path / 'dir'}: is a folder; "
                                                                      "give a file name")
    assert _refused(tmp_path / "gone" / "a.png") == (
        "unwritable", f"{tmp_path / 'gone' / 'a.png'}: the folder {tmp_path / 'gone'} does not exist")
    code, message = _refused(tmp_path / "shot.blend", blend_ok=True, inputs=("", str(tmp_path / "shot.blend")))
    assert code == "overwrite" and message.endswith(f"would overwrite the input {tmp_path / 'shot.blend'}")


def test_an_existing_file_of_another_kind_needs_overwrite(tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me")
    code, message = _refused(notes, what="a PNG image", replaceable=lambda p: False)
    assert code == "overwrite" and message == f"{notes}: exists and is not a PNG image; choose another file"
    assert check_output_file(str(notes), replaceable=lambda p: False, overwrite=True) == str(notes)
    assert check_output_file(str(notes), replaceable=lambda p: p == str(notes)) == str(notes)
    assert notes.read_text() == "keep me"
    code, _ = _refused(notes, inputs=(str(notes),), overwrite=True)  # an input stays refused with overwrite
    assert code == "overwrite"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_pipe_is_refused_unless_devices_are_allowed(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    assert _refused(fifo) == ("not_a_file", f"{fifo}: is not a regular file")


def test_read_only_folder_and_file_are_refused(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    os.chmod(ro, stat.S_IRUSR | stat.S_IXUSR)
    try:
        assert _refused(ro / "a.json") == ("unwritable", f"{ro / 'a.json'}: the folder {ro} is read-only")
    finally:
        os.chmod(ro, stat.S_IRWXU)
    locked = tmp_path / "locked.json"
    locked.write_text("{}")
    os.chmod(locked, stat.S_IRUSR)
    assert _refused(locked) == ("unwritable", f"{locked}: the file is read-only")


def test_same_file_follows_links_and_compares_missing_paths_by_name(tmp_path):
    real = tmp_path / "a.json"
    real.write_text("{}")
    link = tmp_path / "b.json"
    link.symlink_to(real)
    assert same_file(str(link), str(real)) and same_file(str(tmp_path / "x" / ".." / "n"), str(tmp_path / "n"))
    assert not same_file(str(real), str(tmp_path / "n"))
