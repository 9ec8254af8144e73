"""The documentation site: ``python3 -m pip install -e ".[docs]"`` then, from the repository's root,

    python3 -m sphinx -W --keep-going -b html docs docs/_build/html

The docs extra brings the batch and virtual-camera extras the tutorials run (picamera2's python-prctl builds
against the Debian package libcap-dev); darktable-cli and exiftool are used where installed. Warnings are errors:
a broken link or reference, a tutorial command that fails, a gallery example that fails, a public name without a
docstring (``_ext/picamcal_sphinx.py``) each stop the build with the page and the line.
"""

from __future__ import annotations

import sys
from pathlib import Path

import picamcal

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

project = "picamcal"
author = "the picamcal developers"
copyright = "the picamcal developers, GPL-3.0-or-later"
release = version = picamcal.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "sphinx_copybutton",
    "sphinx_design",
    "sphinxcontrib.mermaid",
    "picamcal_sphinx",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "auto_examples/*.ipynb", "auto_examples/*.py"]
templates_path = ["_templates"]

# Every reference must resolve: a broken internal link fails the build. References to other projects' objects
# (numpy's, the standard library's) would need their inventories from the network, so those alone are let be.
nitpicky = True
nitpick_ignore_regex = [
    (r"py:.*", r"(numpy|np|numpy\.typing|npt|pathlib|os|typing|collections|collections\.abc|datetime|enum|io)\..*"),
    (r"py:.*", r"(matplotlib|PIL|dask|distributed|zarr|tifffile|rawpy|colour|picamera2|serial|types|threading)\..*"),
    (r"py:.*", r"(concurrent|multiprocessing|subprocess|argparse|json|re|signal|abc|dataclasses|contextlib)\..*"),
    (r"py:class", r"(ArrayLike|NDArray|Path|PathLike|Callable|Iterable|Iterator|Sequence|Mapping|Any)"),
]

# MyST: the existing Markdown pages as they are, their "#a-heading" links resolved, mermaid diagrams drawn.
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 4
myst_fence_as_directive = ["mermaid"]

# The API reference: one page per public name (written by _ext/picamcal_sphinx.py, stubs by autosummary).
autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"  # the numpydoc Parameters sections give the types, in words
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False

# The gallery: examples/gallery/plot_*.py run at build time on the simulator's small cameras.
sphinx_gallery_conf = {
    "examples_dirs": str(HERE.parent / "examples" / "gallery"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "matplotlib_animations": False,
    "image_scrapers": ("matplotlib",),
    "reset_modules": ("matplotlib",),
    "show_memory": False,
    "plot_gallery": "True",
}

html_theme = "pydata_sphinx_theme"
html_title = f"picamcal {version}"
html_static_path = ["_static"]
html_css_files = ["picamcal.css"]
html_theme_options = {
    "navbar_align": "left",
    "header_links_before_dropdown": 7,
    "show_toc_level": 2,
    "navigation_with_keys": False,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
# Pages of commands and their output want the width: no section navigation beside them (the top bar has it).
html_sidebars = {page: [] for page in ("index", "getting-started", "tutorials/*", "benchmarks", "citing", "changelog")}
html_show_sourcelink = False
copybutton_prompt_text = r">>> |\.\.\. |\$ "
copybutton_prompt_is_regexp = True
copybutton_exclude = ".linenos, .gp, .go"
