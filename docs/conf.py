"""Sphinx configuration of the sb3-cic documentation (``make docs``)."""

import os
import sys
from pathlib import Path

from docutils import nodes
from sphinx import addnodes

# the package is installed (editable) in the environment that builds the docs; the path also lets a
# plain ``sphinx-build`` from a checkout find it
sys.path.insert(0, os.path.abspath(".."))
# nothing is rendered while the API reference imports the modules
os.environ.setdefault("MUJOCO_GL", "disable")

import sb3_cic  # noqa: E402

project = "sb3-cic"
author = "sb3-cic contributors"
copyright = "sb3-cic contributors"
release = version = sb3_cic.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    # Google-style sections ("Args:", "Returns:") of docstrings inherited from gymnasium and SB3
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]
exclude_patterns = ["_build"]

# Markdown pages (MyST): ```{directive} fences, `(target)=` labels, heading anchors for links like
# ``APPENDIX.md#calibration-against-the-reference-code``
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 4

# API reference: one page per module of sb3_cic and envs, generated at build time
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"member-order": "bysource", "show-inheritance": True}
autodoc_typehints = "signature"
autoclass_content = "class"

html_theme = "sphinx_rtd_theme"
html_title = f"sb3-cic {release}"
html_static_path = []
html_theme_options = {"navigation_depth": 3, "collapse_navigation": False}


def _public_objects() -> set[int]:
    """ids of the objects that ``sb3_cic`` and ``envs`` export: the API pages document them under their
    public import path (``sb3_cic.CIC``), so the module pages leave them out instead of repeating them."""
    import envs

    return {id(getattr(package, name)) for package in (sb3_cic, envs) for name in package.__all__}


_PUBLIC = _public_objects()


def _skip_public(app, what, name, obj, skip, options):
    """Skip an exported class or function on its defining module's page (documented on the public page)."""
    if what == "module" and id(obj) in _PUBLIC and not getattr(options, "imported_members", None):
        return True
    return None


def _local_links(app, doctree):
    """Resolve the results pages' links that are not to documents.

    The results pages link to folders of committed run files (``[runs/](runs/)``), which GitHub lists
    but a Sphinx site has no page for: such a link is shown as the folder's path, in code style,
    instead of a broken link.
    """
    docdir = Path(app.env.doc2path(app.env.docname)).parent
    for node in list(doctree.findall(addnodes.pending_xref)):
        if node.get("reftype") != "myst":
            continue
        if node.get("refdomain") is None:
            target = node["reftarget"].split("#", 1)[0]
            if target and (docdir / target).is_dir():
                node.replace_self(nodes.literal(node.astext(), node.astext() or target))


def setup(app):
    app.connect("autodoc-skip-member", _skip_public)
    app.connect("doctree-read", _local_links)
