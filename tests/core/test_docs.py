"""The documentation keeps up with the tree: ARCHITECTURE's capability map names every core and bridge module (and
only modules that exist), the README stays a front door whose commands run, and no documentation ships in the zip.

Static: reads files only (the strict site build is ``mkdocs build --strict`` in tools/run_tests.py; docs/cli.md's
freshness needs Blender: tests/bridge/test_cli_docs.py).
"""
import os
import re
import tomllib

import pytest

import run_tests  # tools/run_tests.py (tests/conftest.py puts tools/ on sys.path)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))
LAYERS = ("core", "bridge")


def _read(*parts) -> str:
    with open(os.path.join(ROOT, *parts), encoding="utf-8") as fh:
        return fh.read()


def _modules(layer: str) -> list[str]:
    """Every module of a layer as a path relative to the root, e.g. ``core/retarget/cloning.py``."""
    found = []
    for folder, dirs, files in os.walk(os.path.join(ROOT, layer)):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        found += [os.path.relpath(os.path.join(folder, f), ROOT).replace(os.sep, "/")
                  for f in sorted(files) if f.endswith(".py")]
    return found


def _map_rows() -> list[dict]:
    """The capability map's table rows of docs/ARCHITECTURE.md as {column header: cell}."""
    text = _read("docs", "ARCHITECTURE.md")
    section = text.split("\n## Capability map\n", 1)[1].split("\n## ", 1)[0]
    lines = [line for line in section.splitlines() if line.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    return [dict(zip(header, (c.strip() for c in line.strip("|").split("|")))) for line in lines[2:]]


def _package_lists(cell: str, layer: str) -> dict[str, set]:
    """``layer/pkg/`` (a, b — an aside —, c) in a cell → {"pkg": {"a", "b", "c"}}: the first word of each item of
    the list in parentheses after the package, asides between em dashes dropped.  Nested packages are keyed by
    their path: `` `core/retarget/sub/` `` → ``"retarget/sub"``."""
    out = {}
    for m in re.finditer(rf"`{layer}/([\w/]+?)/`", cell):
        names = out.setdefault(m[1], set())
        rest = cell[m.end():].lstrip()
        if not rest.startswith("("):
            continue
        depth, end = 0, len(rest)
        for i, ch in enumerate(rest):
            depth += ch == "("
            depth -= ch == ")"
            if depth == 0:
                end = i
                break
        group = re.sub(r"—[^—]*(—|$)", "", rest[1:end])
        names |= {w[0] for item in group.split(",") if (w := re.findall(r"\w+", item))}
    return out


def _top_level(cell: str, layer: str) -> set:
    """Modules named at the layer's top level in a cell: `` `name` `` or `` `layer/name` `` (no trailing slash)."""
    bare = set(re.findall(r"`(\w+)`", cell))
    return bare | set(re.findall(rf"`{layer}/(\w+)`", cell))


def _named(layer: str) -> tuple[set, dict]:
    top, packages = set(), {}
    for row in _map_rows():
        cell = row[layer]
        top |= _top_level(cell, layer)
        for pkg, names in _package_lists(cell, layer).items():
            packages.setdefault(pkg, set()).update(names)
    return top, packages


@pytest.mark.parametrize("layer", LAYERS)
def test_every_module_is_in_the_architecture_map(layer):
    top, packages = _named(layer)
    missing = []
    for rel in _modules(layer):
        parts = rel[:-3].split("/")
        package = "/".join(parts[1:-1])
        if len(parts) == 2 and parts[1] != "__init__":
            ok = parts[1] in top
        elif len(parts) == 2:
            continue  # the layer's own __init__
        elif parts[-1] == "__init__":
            ok = package in packages
        else:
            ok = parts[-1] in packages.get(package, ())
        if not ok:
            missing.append(rel)
    assert not missing, (f"not in docs/ARCHITECTURE.md's capability map ({layer} column): {missing}; name a "
                         f"top-level module as `name`, a package's modules as `{layer}/pkg/` (a, b, …)")


@pytest.mark.parametrize("layer", LAYERS)
def test_the_architecture_map_names_only_modules_that_exist(layer):
    top, packages = _named(layer)
    modules = set(_modules(layer))
    ghosts = [f"{layer}/{pkg}/" for pkg in packages if f"{layer}/{pkg}/__init__.py" not in modules]
    ghosts += [f"{layer}/{pkg}/{name}.py" for pkg, names in packages.items() for name in sorted(names)
               if f"{layer}/{pkg}/{name}.py" not in modules]
    # a bare `name` in the column may also be a symbol (`Status`) or a word: only module-looking ones that exist
    # neither as a module nor as a package are stale
    ghosts += [f"{layer}/{name}" for name in sorted(top)
               if name.islower() and not name.startswith("__") and f"{layer}/{name}.py" not in modules
               and f"{layer}/{name}/__init__.py" not in modules and not _is_symbol(layer, name)]
    assert not ghosts, f"docs/ARCHITECTURE.md's capability map names modules that do not exist: {ghosts}"


def _is_symbol(layer: str, name: str) -> bool:
    """``name`` is defined in some module of the layer (a function or constant the map mentions)."""
    pattern = re.compile(rf"^(def|class) {re.escape(name)}\b|^{re.escape(name)}\s*[:=]", re.M)
    return any(pattern.search(_read(*rel.split("/"))) for rel in _modules(layer))


def _readme_commands() -> list[str]:
    """Shell command lines in the README's fenced blocks (not the ```python snippet)."""
    blocks = re.findall(r"```([a-z]*)\n(.*?)```", _read("README.md"), re.S)
    return [line.strip() for lang, body in blocks if lang != "python" for line in body.splitlines() if line.strip()]


def test_readme_is_a_short_front_door_with_the_two_commands():
    readme = _read("README.md")
    assert len(readme.splitlines()) <= 150
    commands = _readme_commands()
    assert "python tools/demo.py --out out" in commands
    assert "python tools/run_tests.py" in commands


def test_every_readme_command_runs_with_plain_python():
    """Each command is `python tools/<script>.py …`: the script exists and takes the arguments as given."""
    for command in _readme_commands():
        words = command.split()
        assert words[0] == "python" and words[1].startswith("tools/"), command
        assert os.path.isfile(os.path.join(ROOT, words[1])), command
        if words[1] == "tools/run_tests.py":
            run_tests.parse_args(words[2:])        # an unknown --env raises SystemExit


def test_readme_links_resolve():
    for target in re.findall(r"\]\(([^)#\s]+)", _read("README.md")):
        if not re.match(r"[a-z]+:", target):
            assert os.path.exists(os.path.join(ROOT, target)), target


def test_no_documentation_ships_in_the_extension_zip():
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        excluded = tomllib.load(fh)["build"]["paths_exclude_pattern"]
    for pattern in ("/docs/", "/site/", "/mkdocs.yml", "/tools/"):
        assert pattern in excluded, pattern


def test_site_anchors_are_githubs():
    """The site's heading anchors are GitHub's, so `page.md#anchor` links work on both."""
    pytest.importorskip("mkdocs")
    mkdocs_hooks = pytest.importorskip("mkdocs_hooks")      # tools/mkdocs_hooks.py (needs mkdocs)
    assert mkdocs_hooks.github_slug("[0.1.0] - 2026-11-22") == "010---2026-11-22"
    assert mkdocs_hooks.github_slug("Pose-space correctives (thesis ch. 7–8)") == "pose-space-correctives-thesis-ch-78"
    assert mkdocs_hooks.github_slug("Two commands (Python 3.11)") == "two-commands-python-311"
    assert mkdocs_hooks.site_target("docs/user/live.md#networking", "index.md") == "user/live.md#networking"
    assert mkdocs_hooks.site_target("../../CHANGELOG.md", "user/install.md") == "../changelog.md"
    assert mkdocs_hooks.site_target("../../tools/x.py", "user/live.md") == "../../tools/x.py"
