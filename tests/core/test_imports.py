"""First-party imports of ``core/`` and ``bridge/`` (static: the sources are parsed with :mod:`ast`, not imported).

- no function imports anything of the add-on (a cycle is broken by moving code, never by hiding an import);
- the module-level import graph has no cycle;
- ``bridge/posespace/`` keeps the level order its package docstring writes down.
"""
import ast
import os
import re

import pytest

REPO_ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
ADDON_DIRS = ("core", "bridge", "operators", "panels", "properties", "ui", "cli")
#: Paths other helpers of issue #23 are rewriting at the same time (the lead empties this after merging them).
_OTHERS_IN_FLIGHT = ()


def _sources(*tops):
    """``(path relative to the add-on root, absolute path)`` of every .py under ``tops``."""
    for top in tops:
        for root, _, files in os.walk(os.path.join(REPO_ROOT, top)):
            for fname in sorted(files):
                if fname.endswith(".py"):
                    path = os.path.join(root, fname)
                    yield os.path.relpath(path, REPO_ROOT).replace(os.sep, "/"), path


def _in_flight(rel: str) -> bool:
    return rel.startswith(_OTHERS_IN_FLIGHT)


def _tree(path):
    with open(path, encoding="utf-8") as fh:
        return ast.parse(fh.read(), filename=path)


def _module(rel: str) -> str:
    """Dotted name of a source file, e.g. ``bridge/posespace/__init__.py`` → ``bridge.posespace``."""
    return rel[:-3].replace("/", ".").removesuffix(".__init__")


def _package(rel: str) -> list:
    """The package a module's relative imports start from (the package itself for an ``__init__``)."""
    return rel[:-3].split("/")[:-1]


def _first_party(node, rel: str) -> bool:
    """Whether an import statement imports something of the add-on (relative, or absolute by its name)."""
    if isinstance(node, ast.ImportFrom):
        if node.level:
            return True
        names = [node.module or ""]
    elif isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        return False
    return any(n.split(".")[0] in ADDON_DIRS + ("shapespace",) or n.startswith("bl_ext.") for n in names)


MODULES = {_module(rel): rel for rel, _ in _sources("core", "bridge")}


def _targets(node, rel: str) -> list:
    """The add-on modules an import statement of ``rel`` loads: the named modules and the packages above them
    that ``rel`` is not inside (importing ``a.b.c`` runs ``a`` and ``a.b`` first)."""
    if isinstance(node, ast.ImportFrom):
        if node.level:
            pkg = _package(rel)
            base = pkg[: len(pkg) - node.level + 1] + (node.module.split(".") if node.module else [])
        else:
            base = node.module.split(".")
        base = base[1:] if base and base[0] == "shapespace" else base
        named = [".".join(base + [a.name]) for a in node.names if ".".join(base + [a.name]) in MODULES]
        if len(named) < len(node.names):
            named.append(".".join(base))
    else:
        named = [a.name.removeprefix("shapespace.") for a in node.names]
    own = _module(rel).split(".")
    out = []
    for name in named:
        parts = name.split(".")
        out += [".".join(parts[:k]) for k in range(1, len(parts)) if parts[:k] != own[:k]]
        out.append(name)
    return [m for m in dict.fromkeys(out) if m in MODULES]


def _function_imports(tree, rel: str) -> list:
    found = []
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            found += [f"{rel}:{n.lineno} in {getattr(fn, 'name', 'lambda')}()" for n in ast.walk(fn)
                      if _first_party(n, rel)]
    return sorted(set(found))


def _module_level_imports(tree):
    """Import statements run when the module is imported (module body, incl. ``if``/``try`` blocks; not
    functions or classes' methods)."""
    out, stack = [], list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.append(node)
        elif not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            stack += [c for c in ast.iter_child_nodes(node) if isinstance(c, ast.stmt)]
        elif isinstance(node, ast.ClassDef):
            stack += [c for c in node.body if not isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef))]
    return out


def _graph() -> dict:
    """``{module: {module it imports at load time}}`` over core/ and bridge/ (paths in flight left out)."""
    graph = {}
    for rel, path in _sources("core", "bridge"):
        if _in_flight(rel):
            continue
        graph[_module(rel)] = {t for node in _module_level_imports(_tree(path)) if _first_party(node, rel)
                               for t in _targets(node, rel) if not _in_flight(MODULES[t]) and t != _module(rel)}
    return graph


def _cycle(graph: dict) -> list:
    """One import cycle ``[a, b, …, a]`` of ``graph``, or [] when it has none."""
    state, path = {}, []

    def visit(node):
        state[node] = "open"
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        path.pop()
        state[node] = "done"
        return []

    for node in sorted(graph):
        if node not in state:
            found = visit(node)
            if found:
                return found
    return []


# ------------------------------------------------------------------ tests
@pytest.mark.parametrize("rel,path", [s for s in _sources("core", "bridge") if not _in_flight(s[0])],
                         ids=lambda v: v if v.endswith(".py") else "")
def test_no_function_imports_anything_of_the_add_on(rel, path):
    assert not _function_imports(_tree(path), rel), "move these imports to the module top (break a cycle by moving " \
                                                    "code): " + ", ".join(_function_imports(_tree(path), rel))


def test_the_checks_see_function_imports_and_cycles():
    """Guard for the checks themselves, on made-up sources."""
    tree = ast.parse("import numpy\ndef f():\n    import os\n    from . import storage\n"
                     "class C:\n    def m(self):\n        from ..core.result import Issue\n"
                     "def g():\n    import core.names\n")
    assert len(_function_imports(tree, "bridge/x.py")) == 3
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "d": {"a", "c"}}) == []
    node = ast.parse("from ...core.posespace.inversion import invert").body[0]
    assert _targets(node, "bridge/posespace/x.py") == ["core", "core.posespace", "core.posespace.inversion"]
    node = ast.parse("from . import stored, pose").body[0]
    assert _targets(node, "bridge/posespace/__init__.py") == ["bridge.posespace.stored", "bridge.posespace.pose"]
    assert set(_targets(ast.parse("from .. import storage, arrays").body[0], "bridge/posespace/x.py")) == \
        {"bridge.storage", "bridge.arrays"}


def test_the_module_level_import_graph_has_no_cycle():
    graph = _graph()
    assert len(graph) > 60 and "bridge.storage" in graph["bridge.posespace.stored"]
    cycle = _cycle(graph)
    assert not cycle, "import cycle: " + " → ".join(cycle)


# ------------------------------------------------------------------ bridge/posespace level order
POSESPACE = "bridge/posespace"


def _written_levels() -> dict:
    """``{module: level}`` as the package docstring of bridge/posespace writes it."""
    doc = ast.get_docstring(_tree(os.path.join(REPO_ROOT, POSESPACE, "__init__.py")))
    levels = {}
    for number, text in re.findall(r"^- level (\d+): (.*?)(?=^- level |\Z)", doc, re.MULTILINE | re.DOTALL):
        for name in re.findall(r":mod:`\.(\w+)`", text):
            assert name not in levels, f"{name} is written at two levels"
            levels[name] = int(number)
    return levels


def _sibling_imports(name: str) -> set:
    """Modules of bridge/posespace that ``name`` imports, anywhere in the module."""
    rel = f"{POSESPACE}/{name}.py"
    tree = _tree(os.path.join(REPO_ROOT, rel))
    return {t.split(".")[2] for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
            and _first_party(node, rel) for t in _targets(node, rel)
            if t.startswith("bridge.posespace.") and t != f"bridge.posespace.{name}"}


def test_posespace_level_order_is_written_for_every_module():
    modules = {rel.split("/")[-1][:-3] for rel, _ in _sources(POSESPACE)} - {"__init__"}
    assert set(_written_levels()) == modules


def test_posespace_modules_import_only_lower_levels_and_sit_at_their_level():
    levels = _written_levels()
    wrong = []
    for name, level in sorted(levels.items()):
        imported = _sibling_imports(name)
        higher = [f"{n} (level {levels[n]})" for n in sorted(imported) if levels[n] >= level]
        if higher:
            wrong.append(f"{name} (level {level}) imports {', '.join(higher)}")
        elif level != 1 + max((levels[n] for n in imported), default=-1):
            wrong.append(f"{name} is written at level {level}, its imports put it at "
                         f"{1 + max((levels[n] for n in imported), default=-1)}")
    assert not wrong, wrong
