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
# wide tables and long code lines wrap (_static/wrap.css)
html_static_path = ["_static"]
html_css_files = ["wrap.css"]
html_theme_options = {"navigation_depth": 3, "collapse_navigation": False}


def _public_objects() -> set[int]:
    """ids of the objects that ``sb3_cic`` and ``envs`` export: the API pages document them under their
    public import path (``sb3_cic.CIC``), so the module pages leave them out instead of repeating them."""
    from sb3_cic import envs

    return {id(getattr(package, name)) for package in (sb3_cic, envs) for name in package.__all__}


_PUBLIC = _public_objects()


def _method_classes() -> dict[int, type]:
    """URLBDDPG and the ten methods by id: each is documented on its own module's page (``sb3_cic.methods.cic``,
    ``sb3_cic.ddpg``) with a table of its defaults, not on the package page."""
    from sb3_cic.zoo import algorithms

    return {id(cls): cls for cls in algorithms().values()}


_METHODS = _method_classes()


def _skip_public(app, what, name, obj, skip, options):
    """Skip an exported class or function on its defining module's page (documented on the public page); a method
    class the other way round (documented on its module's page, one page per method)."""
    if what != "module":
        return None
    on_package_page = bool(getattr(options, "imported_members", None))
    if id(obj) in _METHODS:
        return True if on_package_page else None
    if id(obj) in _PUBLIC and not on_package_page:
        return True
    return None


def _default_text(name, value) -> str:
    """A default as the table shows it."""
    if value is None and name.endswith("hidden_dim"):
        return "None (the policy's hidden_dim)"
    if name == "policy_kwargs":
        from sb3_cic.policies import URLBPolicy
        from sb3_cic.common.arguments import parameter_default

        value = {"hidden_dim": parameter_default(URLBPolicy, "hidden_dim"), **value}
    if isinstance(value, type):
        return value.__name__
    return repr(value)


def method_defaults(cls) -> list[tuple[str, str]]:
    """``(argument, default)`` of every constructor argument of a method class, as a model built without them has
    them (the class's own defaults, URLBDDPG's, its reward module's and its skill prior's)."""
    import inspect

    from sb3_cic.ddpg import URLBDDPG

    probe = cls("MlpPolicy", None, _init_setup_model=False)
    skip = {"self", "policy", "env", "_init_setup_model", "method_kwargs", "kwargs"}
    names = [n for n in inspect.signature(cls.__init__).parameters if n not in skip]
    names += [n for n in inspect.signature(URLBDDPG.__init__).parameters if n not in skip and n not in names]
    names += [n for n in {**cls.reward_module_args, **cls.skill_prior_args} if n not in names]
    attributes = {"stats_window_size": "_stats_window_size", "sf_dim": "skill_dim"}
    rows = []
    for name in names:
        if name in ("skill_dim", "sf_dim"):
            value = None if probe.skill_prior is None else probe.skill_prior.dim
        else:
            value = getattr(probe, attributes.get(name, name))
        rows.append((name, _default_text(name, value)))
    return rows


def _add_defaults(app, what, name, obj, options, lines):
    """After the docstring of a method class: the table of its defaults (:func:`method_defaults`)."""
    if what != "class" or id(obj) not in _METHODS:
        return
    lines += ["", f"**Defaults** of ``{obj.__name__}`` (each argument not given):", "", ".. list-table::",
              "   :header-rows: 1", "", "   * - argument", "     - default"]
    for argument, default in method_defaults(obj):
        lines += [f"   * - ``{argument}``", f"     - ``{default}``"]
    lines.append("")


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
    app.connect("autodoc-process-docstring", _add_defaults)
    app.connect("doctree-read", _local_links)
