"""
Sphinx configuration of the sb3-offon documentation (Stable-Baselines3's toolchain: Sphinx, MyST, Read the Docs theme).

Build it, warnings as errors, from the repository's root::

    sphinx-build -W docs docs/_build/html

The benchmark reports under ``results/`` (their READMEs, ``table.md`` files and figures) are pages of the site too:
they are copied into ``docs/results/`` (generated, not tracked) when the build starts, so that their relative links
and images work there as they do in the repository.
"""

import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))

# The version is written once, in sb3_offon/version.txt (read by the package and by setuptools too)
release = version = (ROOT / "sb3_offon" / "version.txt").read_text(encoding="utf-8").strip()

project = "sb3-offon"
author = "The sb3-offon contributors"
copyright = "2026, The sb3-offon contributors"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx.ext.mathjax",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
master_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
myst_enable_extensions = ["dollarmath", "colon_fence", "substitution"]
myst_substitutions = {"version": version}
# Anchors for the headings of every page, so that ``page.md#heading`` links resolve (as on GitHub)
myst_heading_anchors = 3

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autosummary_generate = False

html_theme = "sphinx_rtd_theme"
html_title = f"sb3-offon {release}"
html_static_path = ["_static"]
html_css_files = ["css/custom.css"]
html_show_sourcelink = False

# The reports of results/ (no raw runs): Markdown and figures, copied as they are
MIRROR = DOCS / "results"
REPORT_FILES = ("*.md", "*.png")


def copy_reports() -> None:
    shutil.rmtree(MIRROR, ignore_errors=True)
    for folder in sorted(path for path in (ROOT / "results").iterdir() if path.is_dir() and path.name != "raw"):
        for pattern in REPORT_FILES:
            for path in sorted(folder.glob(pattern)):
                target = MIRROR / folder.name / path.name
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(path, target)


copy_reports()


def relink(app, docname: str, source: list[str]) -> None:  # type: ignore[no-untyped-def]
    """
    Links that point out of ``docs/`` in the repository, pointed at the same files inside the site.

    A page of ``docs/`` links to ``../results/...`` (the report, as in the repository); in the site the report is
    ``results/...``. A report links to ``../../docs/page.md``; in the site the page is ``../../page.md``.
    A report without a title gets its file name as one.
    """
    text = source[0]
    if docname.startswith("results/"):
        text = text.replace("](../../docs/", "](../../")
        # The per-run speed tables open with a line of text, not a title: the file's path is the page's title
        # (a generated report's first line is an HTML comment that names its command: the title follows it)
        first = next((line for line in text.splitlines() if line.strip() and not line.startswith("<!--")), "")
        if not first.startswith("# "):
            text = f"# `{docname}.md`\n\n{text}"
    else:
        text = text.replace("](../results/", "](results/")
    source[0] = text


def setup(app) -> None:  # type: ignore[no-untyped-def]
    app.connect("source-read", relink)
