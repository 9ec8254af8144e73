"""The documentation site's own Sphinx extension (docs/conf.py loads it).

- ``commands``: a MyST directive that shows a block of commands (bash, or Python with ``:language: python``) and
  runs it when the site is built, in one folder per page (``docs/_generated/runs/PAGE``, the blocks of a page in
  order, the way a reader follows them), so a tutorial's commands and its pictures come from the same run. A block
  that fails is a warning naming the page and the line, so ``sphinx -W`` fails. ``:output:`` shows what the block
  printed; ``:write: NAME`` writes the block into that file instead of running it (a script the next block runs);
  ``:requires: TOOL`` runs it only where TOOL is installed; ``:not-run: REASON`` shows it with the reason (a
  Raspberry Pi's camera, a cluster). The folder stands for a clone of the repository: ``examples/`` is there.
- The API reference: for each module the toctree of ``docs/api/index.md`` lists, a page
  ``docs/api/MODULE.rst`` whose autosummary table gives every public name of the module (its ``__all__``, else the
  functions and classes it defines) a page of its own in ``docs/api/generated/``. A name that several modules
  export (``picamcal.RawImage`` is ``picamcal.raw.RawImage``) has one page, the first module's.
- The checks: a public function or class of those pages without a docstring, or a public function without a
  ``>>>`` example, is a warning naming its source file and line (so ``sphinx -W`` fails).
"""

from __future__ import annotations

import difflib
import importlib
import inspect
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.application import Sphinx
from sphinx.directives.code import container_wrapper
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

logger = logging.getLogger(__name__)

#: How long one block of commands may run, seconds.
COMMAND_TIMEOUT = 600


# --- commands run at build time ---------------------------------------------------------------------------------


def run_folder(directive: SphinxDirective) -> Path:
    """The page's run folder, emptied when the page's first block runs."""
    folder = Path(directive.env.srcdir) / "_generated" / "runs" / directive.env.docname
    if not directive.env.temp_data.get("picamcal_run_folder"):
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        examples = Path(directive.env.srcdir).parent / "examples"
        if examples.is_dir():
            (folder / "examples").symlink_to(examples, target_is_directory=True)
        directive.env.temp_data["picamcal_run_folder"] = True
    return folder


def shown(printed: str, folder: Path) -> str:
    """What a block printed, as a reader would see it: paths relative to the run folder, the package's own
    folder as ``…/picamcal``."""
    package = Path(importlib.import_module("picamcal").__file__).parent
    text = printed.replace(f"{folder}/", "").replace(str(folder), ".").replace(str(package), "…/picamcal")
    return re.sub(r"\x1b\[[0-9;]*m", "", text).rstrip()


class Commands(SphinxDirective):
    """The ``commands`` directive (see the module's docstring)."""

    has_content = True
    option_spec = {  # noqa: RUF012 (docutils' interface)
        "language": directives.unchanged_required,
        "output": directives.flag,
        "write": directives.unchanged_required,
        "requires": directives.unchanged_required,
        "not-run": directives.unchanged_required,
    }

    def run(self) -> list[nodes.Node]:
        code = "\n".join(self.content)
        language = self.options.get("language", "bash")
        literal = nodes.literal_block(code, code, language=language)
        self.set_source_info(literal)
        name = self.options.get("write")
        result: list[nodes.Node] = [container_wrapper(self, literal, name) if name else literal]
        reason = self.options.get("not-run")
        tool = self.options.get("requires")
        if reason is None and tool and shutil.which(tool) is None:
            reason = f"{tool} is not installed where this page was built"
            logger.info(f"{self.get_location()}: not run: {reason}")
        if reason is not None:
            note = nodes.paragraph("", "", nodes.emphasis("", f"Not run when this site is built: {reason}."))
            note["classes"].append("not-run")
            return [*result, note]
        folder = run_folder(self)
        if name:
            (folder / name).write_text(code + "\n")
            return result
        command = ["bash", "-e", "-o", "pipefail", "-c", code] if language == "bash" else [sys.executable, "-c", code]
        environment = {
            **os.environ,
            "MPLBACKEND": "Agg",
            "COLUMNS": "110",
            "XDG_CONFIG_HOME": str(folder / ".config"),
            "XDG_CACHE_HOME": str(folder / ".cache"),
        }
        started = time.monotonic()
        try:
            done = subprocess.run(
                command,
                cwd=folder,
                env=environment,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                timeout=COMMAND_TIMEOUT,
            )
            printed, failed = done.stdout, done.returncode != 0
        except subprocess.TimeoutExpired as exc:
            printed, failed = f"{exc.output or ''}\n(stopped after {COMMAND_TIMEOUT} s)", True
        logger.info(f"{self.get_location()}: ran in {time.monotonic() - started:.1f} s")
        if failed:
            last = "\n    ".join(shown(printed, folder).splitlines()[-15:])
            logger.warning(f"these commands failed in {folder}:\n    {last}", location=self.get_location())
        if "output" in self.options and printed.strip():
            output = nodes.literal_block(printed, shown(printed, folder), language="text")
            output["classes"].append("command-output")
            self.set_source_info(output)
            result.append(container_wrapper(self, output, "What it prints"))
        return result


# --- the API pages ----------------------------------------------------------------------------------------------


def public_names(module: Any) -> list[str]:
    """A module's public names: its ``__all__``, else the functions and classes it defines."""
    if hasattr(module, "__all__"):
        return list(module.__all__)
    return [
        name
        for name, value in vars(module).items()
        if not name.startswith("_")
        and (inspect.isfunction(value) or inspect.isclass(value))
        and value.__module__ == module.__name__
    ]


def api_modules(index: Path) -> list[str]:
    """The modules the toctree of ``docs/api/index.md`` lists, in its order."""
    block = re.search(r"```\{toctree\}\n(.*?)```", index.read_text(), re.DOTALL)
    if not block:
        raise RuntimeError(f"{index}: no toctree of modules")
    return [line.strip() for line in block.group(1).splitlines() if line.strip() and not line.startswith(":")]


def write_api_pages(app: Sphinx, config: Any) -> None:
    """Write ``docs/api/MODULE.rst`` for every module of the API index (before Sphinx looks for its sources)."""
    api = Path(app.srcdir) / "api"
    documented: dict[int, str] = {}  # id of an object -> the full name of its one page
    app.picamcal_api_names = set()  # type: ignore[attr-defined]
    app.picamcal_api_pages = documented  # type: ignore[attr-defined]
    for module_name in api_modules(api / "index.md"):
        module = importlib.import_module(module_name)
        entries = []
        for name in public_names(module):
            value = getattr(module, name)
            full = f"{module_name}.{name}"
            if inspect.ismodule(value):
                continue
            key = id(value) if inspect.isfunction(value) or inspect.isclass(value) else id(full)
            entries.append(documented.setdefault(key, full))
            app.picamcal_api_names.add(documented[key])  # type: ignore[attr-defined]
        # A module named as a function (picamcal.calibrate, picamcal.correct) is shown, not made a second target.
        own = [entry.removeprefix(f"{module_name}.") for entry in entries if entry.startswith(f"{module_name}.")]
        elsewhere = [entry for entry in entries if not entry.startswith(f"{module_name}.")]
        parent, _, last = module_name.rpartition(".")
        shadowed = bool(parent) and getattr(sys.modules[parent], last, None) is not module
        lines = [
            module_name,
            "=" * len(module_name),
            "",
            f".. automodule:: {module_name}",
            *(["   :no-index:"] if shadowed else []),
            "",
            f".. currentmodule:: {module_name}",
            "",
            *([".. autosummary::", "   :toctree: generated", "   :nosignatures:", ""] if own else []),
            *(f"   {entry}" for entry in own),
            "",
            *(["Also importable from here, documented where they are defined:", ""] if elsewhere else []),
            *(f"- :obj:`~{entry}` (:obj:`{entry}`)" for entry in elsewhere),
            "",
        ]
        page = api / f"{module_name}.rst"
        text = "\n".join(lines)
        if not page.exists() or page.read_text() != text:  # unchanged pages are not read again
            page.write_text(text)


# --- references in docstrings -----------------------------------------------------------------------------------


def find_object(target: str, contexts: list[str]) -> tuple[bool, Any]:
    """The picamcal object a docstring's reference names, looked up as Python would from its module or class
    (attribute access first, as ``picamcal.calibrate`` is the function, then submodules)."""
    for context in contexts:
        parts = (f"{context}.{target}" if context else target).split(".")
        if parts[0] != "picamcal":
            continue
        value: Any = importlib.import_module("picamcal")
        for at in range(1, len(parts)):
            try:
                value = getattr(value, parts[at])
                continue
            except AttributeError:
                pass
            try:  # a submodule not imported yet, or a module shadowed by its function (picamcal.calibrate)
                value = importlib.import_module(".".join(parts[: at + 1]))
            except ImportError:
                try:
                    value = getattr(importlib.import_module(".".join(parts[:at])), parts[at])
                except (ImportError, AttributeError):
                    break
        else:
            return True, value
    if "." not in target:  # a bare name from a summary line shown on another module's page: any picamcal module's
        for module in list(sys.modules.values()):
            if getattr(module, "__name__", "").startswith("picamcal.") and hasattr(module, target):
                return True, getattr(module, target)
    return False, None


def resolve_reference(app: Sphinx, env: Any, node: Any, contnode: nodes.Node) -> nodes.Node | None:
    """A reference to a picamcal name that exists: to its page if it has one under another name (a re-export),
    else shown as code without a link (a private helper, a constant, a submodule that has no page). A name that
    does not exist at all is left to Sphinx, which warns: the build fails on it."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip(".~")
    module, cls = node.get("py:module") or "", node.get("py:class") or ""
    contexts = [f"{module}.{cls}" if cls else "", module, *_parents(module)]
    page_name = node["refdoc"].rpartition("/")[2]
    found, documented = find_object(page_name, [""])  # the object of the page the reference is on
    home = getattr(documented, "__module__", None) if found else None
    if isinstance(home, str):
        contexts += [f"{home}.{documented.__qualname__}" if inspect.isclass(documented) else "", home]
    contexts = [c for c in dict.fromkeys([*contexts, ""]) if c or contexts]
    found, value = find_object(target, contexts)
    if not found and node.get("reftype") == "attr":
        found = _instance_attribute(target, contexts)
    if not found:
        return None
    page = getattr(app, "picamcal_api_pages", {}).get(id(value))
    if page and page != target:
        domain = env.domains["py"]
        linked = domain.resolve_xref(env, node["refdoc"], app.builder, "obj", page, node, contnode)
        if linked is not None:
            return linked
    return contnode


def _instance_attribute(target: str, contexts: list[str]) -> bool:
    """Whether ``Class.name`` (or ``name`` in a class's context) is an attribute its instances get: a field, an
    annotation, or ``self.name = ...`` in its source."""
    owner, _, attribute = target.rpartition(".")
    for context in contexts:
        found, cls = find_object(owner, [context]) if owner else find_object(context, [""])
        if not (found and inspect.isclass(cls)):
            continue
        annotations = {name for klass in cls.__mro__ for name in getattr(klass, "__annotations__", {})}
        try:
            source = inspect.getsource(cls)
        except (OSError, TypeError):
            source = ""
        if attribute in annotations or re.search(rf"self\.{re.escape(attribute)}\s*[:=]", source):
            return True
    return False


def _parents(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:cut]) for cut in range(len(parts) - 1, 0, -1)]


# --- the checks -------------------------------------------------------------------------------------------------


def check_docstring(app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """A public name of the API pages without a docstring, or a public function without an example, is a warning."""
    if name not in getattr(app, "picamcal_api_names", ()) or what not in ("function", "class", "exception", "data"):
        return
    try:
        where = f"{inspect.getsourcefile(obj)}:{inspect.getsourcelines(obj)[1]}"
    except (TypeError, OSError):
        where = name
    text = "\n".join(lines)
    if what == "data":
        # A constant without a ``#:`` comment of its own would show its type's docstring (numpy's ndarray's).
        own = difflib.SequenceMatcher(None, text[:2000], (type(obj).__doc__ or "")[:2000]).quick_ratio() < 0.9
        if not own:
            lines[:] = []
        return
    if not text.strip():
        logger.warning(f"{name} has no docstring: every public name needs one (numpydoc)", location=where)
    elif what == "function" and ">>>" not in text:
        logger.warning(f"{name}'s docstring has no example (>>>): every public function needs one", location=where)


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("commands", Commands)
    app.connect("config-inited", write_api_pages)  # before Sphinx finds the sources and autosummary writes stubs
    app.connect("autodoc-process-docstring", check_docstring, priority=100)  # the docstring as written
    app.connect("missing-reference", resolve_reference)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
