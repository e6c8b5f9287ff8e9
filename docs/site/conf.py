"""Sphinx configuration of the iscc-gym documentation site.

Build it (warnings are errors, as in the tests and CI)::

    python -m sphinx -W --keep-going -b html docs/site docs/site/_build/html

Sphinx rather than MkDocs: the docstrings are numpydoc with ``.. math::`` blocks citing the paper's
equation labels and ``:func:`` cross-references, which Sphinx's autodoc and numpydoc read as written
(mkdocstrings would need them rewritten); the existing Markdown pages (``docs/model.md``,
``docs/results.md``, ``docs/learning.md``) come in unchanged through myst-parser's ``include``.
"""

import os
import sys
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(HERE, "_ext"))
if ROOT not in sys.path:  # the checkout's iscc_gym, also where it is not installed in editable mode
    sys.path.insert(0, ROOT)
# autodoc imports the modules: a quiet, single-threaded import (no compile note on stderr, no thread pools)
os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import iscc_gym  # noqa: E402

project = "iscc-gym"
author = "iscc-gym maintainers"
copyright = "2026, iscc-gym maintainers"
release = version = iscc_gym.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "iscc_site",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store"]
root_doc = "index"

# MyST: GitHub-style heading anchors so that pages can link to sections of the included model.md
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 4

# autodoc + numpydoc: members as listed in each module's __all__, in source order; no autosummary stubs
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "show-inheritance": False}
# our API, not Gymnasium's: a method without a docstring of its own shows none (gymnasium.Env's are Google style)
autodoc_inherit_docstrings = False
autodoc_typehints = "none"  # the numpydoc Parameters sections carry types with their units
autosummary_generate = False
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
# numpydoc also reads a class's raw docstring for its signature and warns there of a section named ``Arguments``;
# the docstring it renders has it as ``Parameters`` (_ext/iscc_site.py, section_aliases)
warnings.filterwarnings("ignore", message="Unknown section Arguments", category=UserWarning)

html_theme = "furo"
html_title = f"iscc-gym {release}"
html_static_path = []
pygments_style = "sphinx"
