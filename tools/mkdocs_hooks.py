"""MkDocs hooks (``hooks:`` in mkdocs.yml): the repository's README and CHANGELOG as pages, GitHub's heading anchors.

The Markdown files stay correct where they are read most, on the repository host: README.md and CHANGELOG.md
live at the root and every page links to them and to ``docs/`` by relative paths.  The site gets

- ``index.md`` = README.md and ``changelog.md`` = CHANGELOG.md, generated (not copied into ``docs/``);
- every relative link that points at README.md, CHANGELOG.md or a file under ``docs/`` rewritten to the
  page that holds it in the site (any other link is left as written, so ``--strict`` fails on it);
- heading anchors made as GitHub makes them (:func:`github_slug`), so ``page.md#anchor`` works on both.
"""
from __future__ import annotations

import os
import re
import unicodedata

from mkdocs.structure.files import File

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = os.path.join(ROOT, "docs")
#: repository files shown as generated pages: site page → file at the repository root
GENERATED = {"index.md": "README.md", "changelog.md": "CHANGELOG.md"}
_LINK = re.compile(r"(\]\()([^)\s]+)(\))")
_EXTERNAL = re.compile(r"^([a-z][a-z0-9+.-]*:|#|/)", re.I)


def github_slug(value: str, separator: str = "-") -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, each space a hyphen.

    ``"[0.1.0] - 2026-11-22"`` → ``"010---2026-11-22"`` (Python-Markdown's own slugify would merge the hyphens).
    """
    value = unicodedata.normalize("NFKC", value).strip().lower()
    value = "".join(ch for ch in value if ch.isalnum() or ch in " -_")
    return value.replace(" ", separator)


def source_path(src_uri: str) -> str:
    """Where a site page's Markdown lives in the repository."""
    if src_uri in GENERATED:
        return os.path.join(ROOT, GENERATED[src_uri])
    return os.path.join(DOCS, *src_uri.split("/"))


def site_target(target: str, src_uri: str) -> str:
    """A relative link of page ``src_uri``, as the site needs it (unchanged when it is not ours to map)."""
    if _EXTERNAL.match(target):
        return target
    path, hash_, anchor = target.partition("#")
    resolved = os.path.normpath(os.path.join(os.path.dirname(source_path(src_uri)), path))
    page = {os.path.join(ROOT, repo): site for site, repo in GENERATED.items()}.get(resolved)
    if page is None:
        if os.path.commonpath([resolved, DOCS]) != DOCS:
            return target
        page = os.path.relpath(resolved, DOCS).replace(os.sep, "/")
    here = os.path.dirname(src_uri)
    new = os.path.relpath(page, here or ".").replace(os.sep, "/")
    return new + hash_ + anchor


def rewrite_links(markdown: str, src_uri: str) -> str:
    return _LINK.sub(lambda m: m[1] + site_target(m[2], src_uri) + m[3], markdown)


def on_config(config):
    config.mdx_configs.setdefault("toc", {})["slugify"] = github_slug
    return config


def on_files(files, config):
    for page, repo_file in GENERATED.items():
        with open(os.path.join(ROOT, repo_file), encoding="utf-8") as fh:
            files.append(File.generated(config, page, content=fh.read()))
    return files


def on_page_markdown(markdown, page, config, files):
    return rewrite_links(markdown, page.file.src_uri)
