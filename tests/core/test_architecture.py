"""The layering rules of docs/ARCHITECTURE.md, as tests (static: they read the sources, import nothing of Blender).

- every core module imports with ``bpy``/``mathutils`` absent;
- core imports nothing above it; no core capability package imports another;
- bridge never imports operators, panels, ui or cli; operators and panels reach Blender data only through bridge
  (no attribute writes on Blender data, no custom-property writes, no datablock/collection creation or removal);
- every error code raised anywhere is listed in ``core.errors.ErrorCode``;
- no star imports; public core functions and methods are annotated.
"""
import ast
import os
import subprocess
import sys

import pytest

from core.errors import ErrorCode

REPO_ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
CAPABILITIES = ("manipulation", "posespace", "retarget", "facespace", "live", "export", "authoring")
ADDON_DIRS = ("core", "bridge", "operators", "panels", "properties", "ui", "cli")


def _sources(*dirs):
    for top in dirs:
        for root, _, files in os.walk(os.path.join(REPO_ROOT, top)):
            for fname in sorted(files):
                if fname.endswith(".py"):
                    path = os.path.join(root, fname)
                    yield os.path.relpath(path, REPO_ROOT).replace(os.sep, "/"), path


def _tree(path):
    with open(path, encoding="utf-8") as fh:
        return ast.parse(fh.read(), filename=path)


def _package_of(rel):
    """Dotted package of a module path relative to the add-on root, e.g. ``core/retarget/x.py`` → core.retarget."""
    parts = rel[:-3].split("/")
    return parts[:-1] if parts[-1] != "__init__" else parts[:-1]


def _imported_modules(rel, tree):
    """Absolute (add-on-relative) dotted names imported by a module, resolving relative imports."""
    pkg = _package_of(rel)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
                if node.module is None:
                    out += [f"{mod}.{a.name}" for a in node.names]
                else:
                    out.append(mod)
                    out += [f"{mod}.{a.name}" for a in node.names]
            else:
                out.append(node.module or "")
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names]
    return out


CORE_MODULES = sorted(rel[:-3].replace("/", ".").removesuffix(".__init__") for rel, _ in _sources("core"))


def test_every_core_module_imports_without_blender():
    code = (
        "import importlib, sys\n"
        "sys.modules['bpy'] = None\n"
        "sys.modules['mathutils'] = None\n"
        f"sys.path.insert(0, {REPO_ROOT!r})\n"
        f"for name in {CORE_MODULES!r}:\n"
        "    importlib.import_module(name)\n"
        "print('OK', len(sys.modules))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          cwd=os.path.dirname(REPO_ROOT))
    assert proc.returncode == 0, proc.stderr
    assert len(CORE_MODULES) > 20


@pytest.mark.parametrize("rel,path", list(_sources("core")), ids=lambda v: v if v.endswith(".py") else "")
def test_core_imports_nothing_above_it_and_no_other_capability(rel, path):
    own = _package_of(rel)
    own_cap = own[1] if len(own) > 1 and own[1] in CAPABILITIES else None
    for name in _imported_modules(rel, _tree(path)):
        root = name.split(".")[0]
        assert root not in ("bpy", "mathutils", "gpu", "bmesh", "bpy_extras"), f"{rel} imports {name}"
        assert root not in ADDON_DIRS[1:], f"{rel} imports {name} (core must not import the layers above it)"
        parts = name.split(".")
        if root == "core" and len(parts) > 1 and parts[1] in CAPABILITIES:
            assert own_cap == parts[1] or own_cap is None and parts[1] in CAPABILITIES and rel == "core/__init__.py", \
                f"{rel} imports {name}: a core capability package may use only the foundation modules"


@pytest.mark.parametrize("rel,path", list(_sources("bridge")), ids=lambda v: v if v.endswith(".py") else "")
def test_bridge_imports_only_core(rel, path):
    for name in _imported_modules(rel, _tree(path)):
        root = name.split(".")[0]
        assert root not in ("operators", "panels", "ui", "cli", "properties"), f"{rel} imports {name}"


@pytest.mark.parametrize("rel,path", list(_sources("operators", "panels", "ui", "cli")),
                         ids=lambda v: v if v.endswith(".py") else "")
def test_upper_layers_do_not_import_each_other_downwards_only(rel, path):
    layer = rel.split("/")[0]
    allowed = {"operators": {"bridge", "core", "properties", "operators"},
               "panels": {"bridge", "core", "properties", "panels"},
               "ui": {"bridge", "core", "ui"},
               "cli": {"bridge", "core", "cli"}}[layer]
    for name in _imported_modules(rel, _tree(path)):
        root = name.split(".")[0]
        if root in ADDON_DIRS:
            assert root in allowed, f"{rel} imports {name}"


# Attribute writes that only configure the UI (layout) or the operator itself are not data writes.
_UI_ATTRS = {"enabled", "active", "alert", "use_property_split", "use_property_decorate", "scale_x", "scale_y",
             "alignment", "operator_context", "emboss", "ui_units_x", "ui_units_y", "active_default"}
_OWN_ROOTS = {"self", "op", "props"}        # the operator's own properties / an operator button's properties
_WRITE_CALLS = {"new", "remove", "clear", "add", "foreach_set", "keyframe_insert", "keyframe_delete",
                "driver_add", "driver_remove", "frame_set", "update_tag", "move", "link", "unlink",
                "shape_key_add", "shape_key_remove", "modifier_add", "transform_apply"}


def _root(node):
    while isinstance(node, (ast.Attribute, ast.Subscript)):
        node = node.value
    return node.id if isinstance(node, ast.Name) else None


def _operator_buttons(tree):
    """Names bound to ``layout.operator(...)`` buttons: setting their properties configures a button."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call) and _is_button(node.value):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return names


def _is_button(node):
    return isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
        node.func.attr in ("operator", "operator_menu_enum")


def _button_root(node):
    while isinstance(node, (ast.Attribute, ast.Subscript)):
        node = node.value
    return _is_button(node)


def _data_writes(tree):
    found = []
    own = _OWN_ROOTS | _operator_buttons(tree)
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, (ast.Assign,)):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        for t in targets:
            for sub in ast.walk(t):
                if isinstance(sub, ast.Attribute) and isinstance(sub.ctx, ast.Store):
                    if _root(sub) not in own and sub.attr not in _UI_ATTRS and not _button_root(sub):
                        found.append((node.lineno, ast.unparse(sub)))
                if isinstance(sub, ast.Subscript) and isinstance(sub.ctx, ast.Store):
                    found.append((node.lineno, ast.unparse(sub)))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in _WRITE_CALLS:
            if _root(node.func) not in own:
                found.append((node.lineno, ast.unparse(node.func)))
        if isinstance(node, ast.Delete):
            found.append((node.lineno, ast.unparse(node)))
    return found


@pytest.mark.parametrize("rel,path", list(_sources("operators", "panels")),
                         ids=lambda v: v if v.endswith(".py") else "")
def test_operators_and_panels_write_no_data(rel, path):
    writes = _data_writes(_tree(path))
    assert not writes, f"{rel} writes Blender data itself (use a bridge verb): {writes}"


def _raised_codes():
    for rel, path in _sources(*ADDON_DIRS):
        for node in ast.walk(_tree(path)):
            if not isinstance(node, ast.Call):
                continue
            fname = getattr(node.func, "id", getattr(node.func, "attr", None))
            code = None
            if fname == "ShapeSpaceError":
                code = node.args[1] if len(node.args) > 1 else None
                for kw in node.keywords:
                    if kw.arg == "code":
                        code = kw.value
            elif fname == "Issue" and node.args and isinstance(node.args[0], ast.Constant) \
                    and node.args[0].value == "error" and len(node.args) > 1:
                code = node.args[1]
            if isinstance(code, ast.Constant):
                yield rel, node.lineno, code.value
            elif isinstance(code, ast.Attribute) and _root(code) == "ErrorCode":
                yield rel, node.lineno, code.attr.lower()


def test_every_raised_error_code_is_listed():
    known = {c.value for c in ErrorCode}
    unknown = [(rel, line, code) for rel, line, code in _raised_codes() if code not in known]
    assert not unknown, f"error codes missing from core/errors.py: {unknown}"
    assert len(list(_raised_codes())) > 150


def test_no_star_imports():
    stars = [(rel, node.lineno) for rel, path in _sources(*ADDON_DIRS, "tools", "tests")
             for node in ast.walk(_tree(path))
             if isinstance(node, ast.ImportFrom) and any(a.name == "*" for a in node.names)]
    assert not stars, stars


def _public_callables(tree):
    """Public module-level functions and public methods of public classes (name, node)."""
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
            yield node.name, node
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            for item in node.body:
                if isinstance(item, ast.FunctionDef) and not item.name.startswith("_"):
                    yield f"{node.name}.{item.name}", item


def _unannotated(fn):
    args = fn.args
    params = args.posonlyargs + args.args + args.kwonlyargs
    missing = [a.arg for a in params if a.annotation is None and a.arg not in ("self", "cls")]
    for extra in (args.vararg, args.kwarg):
        if extra is not None and extra.annotation is None:
            missing.append("*" + extra.arg)
    is_property = any(getattr(d, "id", None) in ("property", "cached_property") for d in fn.decorator_list)
    if fn.returns is None and fn.name != "__init__" and not is_property:
        missing.append("return")
    elif fn.returns is None and is_property:
        missing.append("return")
    return missing


def test_public_core_signatures_are_annotated():
    gaps = []
    for rel, path in _sources("core"):
        for name, fn in _public_callables(_tree(path)):
            missing = _unannotated(fn)
            if missing:
                gaps.append(f"{rel}:{fn.lineno} {name}: {', '.join(missing)}")
    assert not gaps, "unannotated public core signatures:\n" + "\n".join(gaps)


def test_property_groups_have_no_python_callbacks():
    """``update=``/``poll=``/``get=``/``set=`` callbacks on PropertyGroup fields crash Blender 4.2 (as a Python
    module) at exit; settings are validated where they are used instead."""
    found = []
    for rel, path in _sources("properties"):
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "").endswith("Property"):
                found += [(rel, node.lineno, kw.arg) for kw in node.keywords
                          if kw.arg in ("update", "poll", "get", "set")]
    assert not found, found


def test_test_file_basenames_are_unique():
    """pytest imports test files by basename (rootdir tests/, no packages): two ``test_x.py`` collide."""
    seen = {}
    for rel, _ in _sources("tests"):
        name = rel.rsplit("/", 1)[-1]
        if name.startswith("test_"):
            seen.setdefault(name, []).append(rel)
    assert not {k: v for k, v in seen.items() if len(v) > 1}
