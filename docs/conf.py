"""Sphinx configuration of the vesselid documentation.

Build it with ``sphinx-build -W --keep-going -b html docs docs/_build/html`` (the ``docs``
extra installs what it needs). Pages are MyST Markdown; pages with ``file_format: mystnb``
front matter are notebooks whose code cells run on every build, so a failing or stale
example fails the build.
"""

from __future__ import annotations

import os
from pathlib import Path

# The package is documented as installed (``pip install ".[docs]"`` or ``-e``): its
# ``vesselid.envs`` subpackage lives in the folder ``envs/`` and exists only once installed.
ROOT = Path(__file__).resolve().parent.parent
os.environ.setdefault("MPLBACKEND", "Agg")
# the executed pages run in a temporary folder: this tells them where the repository is
# (the study scripts and the tables they generate)
os.environ["VESSELID_REPO"] = str(ROOT)

import vesselid  # noqa: E402

project = "vesselid"
author = "vesselid developers"
copyright = "vesselid developers, MIT licence"
version = release = vesselid.__version__

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb"}
root_doc = "index"
exclude_patterns = ["_build", "**.ipynb_checkpoints", "Thumbs.db", ".DS_Store"]

# MyST / MyST-NB: every code cell runs when the docs build; an error fails the build.
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = os.environ.get("VESSELID_DOCS_EXECUTE", "cache")
nb_execution_raise_on_error = True
nb_execution_timeout = 600
nb_execution_cache_path = str(ROOT / "docs" / "_build" / ".jupyter_cache")
nb_merge_streams = True

# API reference from the numpydoc docstrings.
autosummary_generate = True
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"
autoclass_content = "class"
napoleon_numpy_docstring = True
napoleon_google_docstring = False
napoleon_use_rtype = False
napoleon_preprocess_types = False

html_theme = "pydata_sphinx_theme"
html_title = f"vesselid {release}"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
}
autodoc_inherit_docstrings = False
# Re-exports (``vesselid.ModelSpec`` is ``vesselid.model.spec.ModelSpec``) make two targets for
# one name; either is the same object.
suppress_warnings = ["ref.python"]
# Each page's cells run in a fresh temporary directory: files they write stay out of docs/.
nb_execution_in_temp = True
