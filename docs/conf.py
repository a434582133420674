"""Sphinx configuration of the gym_gridloc documentation (furo theme, MyST markdown).

Build: ``python -m sphinx -W --keep-going -n -b html docs docs/_build/html`` (needs the ``docs``
extra). The environment pages (``docs/envs/*.md``) are written at build time from the classes'
docstrings and the registry by ``docs/_ext/gridloc_envs.py``; never edit them by hand.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

import gym_gridloc  # the installed package: autodoc documents what users import

project = "gym_gridloc"
author = "the gym_gridloc authors"
copyright = "2026, the gym_gridloc authors"
release = gym_gridloc.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "gridloc_envs",  # docs/_ext: the environment pages, written from the docstrings
    "gridloc_docstrings",  # docs/_ext: NumPy sections, references resolved as Python would
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path: list[str] = []

# -- MyST --------------------------------------------------------------------------------------------
myst_enable_extensions = ["attrs_block", "colon_fence", "deflist", "dollarmath"]
# Anchors for headings down to level 3, so that [text](page.md#a-heading) links are checked too.
myst_heading_anchors = 3

# -- links: every internal reference must resolve ------------------------------------------------------
# Nitpicky mode (-n, or this setting) warns about every cross-reference that does not resolve; with
# -W that fails the build. Only names of other projects are exempt: the build runs offline, so there
# is no intersphinx inventory for numpy, gymnasium or the standard library.
nitpicky = True
nitpick_ignore_regex = [
    (r"py:.*", r"(numpy|np|numpy\.typing|npt|scipy|gymnasium|gym|typing|typing_extensions|collections|"
               r"collections\.abc|pathlib|os|enum|dataclasses|functools|abc)(\..*)?"),
    (r"py:.*", r"(Any|Callable|Iterable|Iterator|Sequence|Mapping|Optional|Union|Literal|Self|"
               r"ndarray|NDArray|ArrayLike|Generator|SeedSequence|Path|PathLike|Env|Wrapper|Space|"
               r"ObsType|ActType|RenderFrame|WrapperObsType|Discrete|MultiBinary|Box|Dict|"
               r"VectorEnv|AutoresetMode|SupportsFloat|spmatrix|csr_matrix|sparray)"),
    (r"py:class", r"(int|float|str|bool|bytes|object|tuple|list|dict|set|frozenset|type|None|"
                  r"slice|complex|Ellipsis|range|memoryview|bytearray|Exception|ValueError|TypeError)"),
]

# -- autodoc -----------------------------------------------------------------------------------------
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
autodoc_default_options = {"members": True}
# The package's own docstrings only: an inherited one (gymnasium's Env.reset, ...) refers to names
# documented in gymnasium's reference, not here.
autodoc_inherit_docstrings = False

# -- HTML --------------------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"gym_gridloc {release}"
html_static_path = ["_static"]
html_css_files = ["gridloc.css"]
html_show_sourcelink = False
