"""The registry of stored data (:mod:`core.blobs`): every blob ShapeSpace keeps in a .blend is declared there.

Static half (the sources are parsed, nothing of Blender imported): a :class:`core.schema.Schema` is made only in
``core/blobs.py``, and every schema made there is registered.  The real-Blender half (every registered blob is
upgraded on save and diagnosed by Check Rig; every ``Schema`` reachable from a module of the add-on is
registered) is ``tests/bridge/test_stored_data.py``.
"""
import ast
import importlib
import os
import pkgutil

import core
from core import blobs
from core.schema import Schema, loads

REPO_ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
ADDON_DIRS = ("core", "bridge", "operators", "panels", "properties", "ui", "cli")
REGISTRY = "core/blobs.py"


def _sources():
    yield "__init__.py", os.path.join(REPO_ROOT, "__init__.py")
    for top in ADDON_DIRS:
        for root, _, files in os.walk(os.path.join(REPO_ROOT, top)):
            for fname in sorted(files):
                if fname.endswith(".py"):
                    path = os.path.join(root, fname)
                    yield os.path.relpath(path, REPO_ROOT).replace(os.sep, "/"), path


def _schema_calls(path) -> list:
    """Line numbers of every ``Schema(...)`` / ``x.Schema(...)`` call in a source file."""
    with open(path, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), filename=path)
    return [node.lineno for node in ast.walk(tree) if isinstance(node, ast.Call)
            and (getattr(node.func, "id", None) == "Schema" or getattr(node.func, "attr", None) == "Schema")]


def test_a_schema_is_made_only_in_the_registry():
    made = {rel: lines for rel, path in _sources() if (lines := _schema_calls(path))}
    assert REGISTRY in made
    elsewhere = {rel: lines for rel, lines in made.items() if rel != REGISTRY}
    assert not elsewhere, f"declare these blobs in {REGISTRY} and import their schema from there: {elsewhere}"


def test_every_schema_made_in_the_registry_is_registered():
    registered = {id(s) for s in blobs.schemas()}
    # the registry's own module level, and every Schema(...) call in it: one registered schema each
    loose = [name for name, value in vars(blobs).items() if isinstance(value, Schema) and id(value) not in registered]
    assert not loose, loose
    assert len(_schema_calls(os.path.join(REPO_ROOT, REGISTRY))) == len(registered)


def test_every_core_module_keeps_only_registered_schemas():
    registered = {id(s) for s in blobs.schemas()}
    stray = []
    for info in pkgutil.walk_packages(core.__path__, "core."):
        module = importlib.import_module(info.name)
        stray += [f"{info.name}.{n}" for n, v in vars(module).items() if isinstance(v, Schema)
                  and id(v) not in registered]
    assert not stray, stray


def test_the_three_blobs_storage_used_to_miss_are_registered():
    owned = {(b.owner, b.prop) for b in blobs.BLOBS}
    assert {("Object", "shapespace_landmarks"), ("Action", "shapespace_live_take"),
            ("Example", "final_shape")} <= owned


def test_each_blob_has_a_known_owner_one_place_and_a_sound_schema():
    places = [(b.owner, b.prop) for b in blobs.BLOBS]
    assert len(set(places)) == len(places)
    names = [s.name for s in blobs.schemas()]
    assert len(set(names)) == len(names)
    for blob in blobs.BLOBS:
        assert blob.owner in blobs.OWNERS, blob
        assert blob.on_id == (blob.owner != "Example")
        assert blob.prop.startswith("shapespace_") or not blob.on_id, blob
        for schema in (blob.schema, *blob.sections.values()):
            assert schema.version >= 1 and all(0 <= v < schema.version for v in schema.migrations), schema.name
            assert loads(None, schema, blob.prop) == {"schema_version": schema.version,
                                                     **({"values": []} if schema.list_blob else {})}
