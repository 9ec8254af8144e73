"""The documentation site (docs/conf.py) builds from the repository with warnings as errors, and what it must hold is
there: an API page with its example for every public name, every tutorial with its pictures, the gallery; a broken
link, a failing tutorial command or a public function without a docstring fails the build with its page and line.
Also: the citation, the changelog, the benchmark figures' page, and the short README with its commands run on the
simulator."""

from __future__ import annotations

import inspect
import os
import re
import runpy
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
TUTORIALS = ["microscope-white", "full-rig", "batch", "darktable", "live", "virtual-camera", "napari"]
#: What the build writes into the source folder, left out of the copy it builds from.
GENERATED = ("_build", "_generated", "auto_examples", "generated", "picamcal*.rst", "sg_execution_times.rst")
SITE_PACKAGES = (
    "sphinx",
    "pydata_sphinx_theme",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery",
    "sphinx_copybutton",
    "sphinx_design",
    "sphinxcontrib.mermaid",
)


def extension():
    """docs/_ext/picamcal_sphinx.py, the site's own extension, as a namespace."""
    return runpy.run_path(str(DOCS / "_ext" / "picamcal_sphinx.py"))


def needs_sphinx() -> None:
    for package in SITE_PACKAGES:
        pytest.importorskip(package, reason=f"the site needs {package}: python3 -m pip install -e '.[docs]'")


def build(source: Path, out: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(source), str(out)]
    # A guard against a hang, not a time limit: on 2 cores busy with other work the build took over 25 minutes.
    return subprocess.run(command, capture_output=True, text=True, timeout=3600)


def copy_repository(into: Path) -> Path:
    """What the site is built from (docs, examples, the changelog it includes, the citation), without what a
    previous build generated."""
    shutil.copytree(DOCS, into / "docs", ignore=shutil.ignore_patterns(*GENERATED))
    shutil.copytree(ROOT / "examples", into / "examples", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("CHANGELOG.md", "CITATION.cff"):
        shutil.copy(ROOT / name, into / name)
    return into / "docs"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The whole site, built once (about two minutes on 2 cores)."""
    needs_sphinx()
    work = tmp_path_factory.mktemp("site")
    result = build(copy_repository(work / "repo"), work / "html")
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-6000:]
    return work / "html"


@pytest.mark.slow
def test_every_public_name_has_an_api_page_with_its_example(site):
    names = extension()
    modules = names["api_modules"](DOCS / "api" / "index.md")
    missing, without_example = [], []
    for module_name in modules:
        page = site / "api" / f"{module_name}.html"
        assert page.exists(), f"no page for the module {module_name}"
        module = __import__(module_name, fromlist=["_"])
        for name in names["public_names"](module):
            value = getattr(module, name)
            if isinstance(value, type(sys)):
                continue
            # A name exported by several modules has one page, under the first module that lists it.
            pages = list((site / "api" / "generated").glob(f"*.{name}.html"))
            if not pages:
                missing.append(f"{module_name}.{name}")
            elif inspect.isfunction(value):
                if not any("Examples" in path.read_text() and "&gt;&gt;&gt;" in path.read_text() for path in pages):
                    without_example.append(f"{module_name}.{name}")
    assert not missing, f"public names without an API page: {missing}"
    assert not without_example, f"functions whose API page shows no example: {without_example}"
    assert "picamcal.calibrate" in (site / "api" / "generated" / "picamcal.calibrate.html").read_text()


@pytest.mark.slow
def test_every_tutorial_is_there_with_its_commands_run_and_its_pictures(site):
    for name in TUTORIALS:
        page = site / "tutorials" / f"{name}.html"
        assert page.exists(), f"no tutorial {name}"
        html = page.read_text()
        for source in re.findall(r'<img [^>]*src="([^"]+)"', html):
            assert (page.parent / source).resolve().is_file(), f"{name}: missing picture {source}"
    microscope = (site / "tutorials" / "microscope-white.html").read_text()
    # What the commands printed when the site was built, shown under them.
    assert "What it prints" in microscope and "wrote flat.npz" in microscope
    assert microscope.count("<img ") == 3
    assert (site / "tutorials" / "full-rig.html").read_text().count("<img ") == 6
    darktable = (site / "tutorials" / "darktable.html").read_text()
    assert ("Not run when this site is built" in darktable) == (shutil.which("darktable-cli") is None)


@pytest.mark.slow
def test_the_gallery_and_the_other_pages_are_there(site):
    gallery = (site / "auto_examples" / "index.html").read_text()
    for example in sorted((ROOT / "examples" / "gallery").glob("plot_*.py")):
        assert (site / "auto_examples" / f"{example.stem}.html").exists(), example.name
        assert (site / "_images" / f"sphx_glr_{example.stem}_001.png").exists(), example.name
        assert example.stem in gallery
    for page in ("index", "getting-started", "benchmarks", "citing", "changelog", "reference/index", "api/index"):
        assert (site / f"{page}.html").exists(), page
    for page in sorted(DOCS.glob("*.md")):
        if not page.name.startswith("_"):
            assert (site / f"{page.stem}.html").exists(), f"{page.name} is not in the site"
    # The benchmarks page shows the figures benchmarks/run.py --write-docs wrote, and names the machine.
    benchmarks = (site / "benchmarks.html").read_text()
    assert "===== calibration =====" in benchmarks and "Intel(R) Xeon(R) Processor" in benchmarks
    assert "10.5334/joh.20" in (site / "citing.html").read_text()


@pytest.mark.slow
def test_a_broken_link_a_failing_command_or_a_missing_docstring_fails_the_build(tmp_path):
    # The site's own configuration on a small source: one page with a broken link, a broken reference and a
    # failing command, and an API page of a module with a function without a docstring and one without example.
    needs_sphinx()
    docs = tmp_path / "docs"
    shutil.copytree(DOCS / "_ext", docs / "_ext", ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("conf.py", "_static", "_templates"):
        (shutil.copytree if (DOCS / name).is_dir() else shutil.copy)(DOCS / name, docs / name)
    (tmp_path / "examples" / "gallery").mkdir(parents=True)
    shutil.copy(ROOT / "examples" / "gallery" / "GALLERY_HEADER.rst", tmp_path / "examples" / "gallery")
    (docs / "api").mkdir()
    (docs / "api" / "index.md").write_text("# API\n\n```{toctree}\nsitecheck\n```\n")
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "sitecheck.py").write_text(
        textwrap.dedent('''
            """A module of the test."""

            __all__ = ["documented", "undocumented"]


            def documented():
                """Say nothing, with no example."""


            def undocumented():
                pass
            ''')
    )
    (docs / "index.md").write_text(
        textwrap.dedent("""
            # A page

            [a page that is not there](nowhere.md) and {py:func}`picamcal.no_such_function`

            ```{commands}
            picamcal calibrate --white no-such-white.dng --out cal.npz
            ```

            ```{toctree}
            api/index
            auto_examples/index
            ```
            """)
    )
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(docs), str(tmp_path / "html")],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "PYTHONPATH": str(tmp_path / "pkg")},
    )
    assert result.returncode != 0
    printed = result.stderr
    assert re.search(r"index\.md:4: WARNING: .*nowhere\.md", printed), printed
    assert re.search(r"index\.md:4: WARNING: py:func reference target not found: picamcal\.no_such_function", printed)
    assert re.search(r"index\.md:6: WARNING: these commands failed .*\n.*no-such-white\.dng", printed), printed
    assert re.search(r"sitecheck\.py:11: WARNING: sitecheck\.undocumented has no docstring", printed), printed
    assert re.search(r"sitecheck\.py:7: WARNING: sitecheck\.documented's docstring has no example", printed), printed


# --- the short README -------------------------------------------------------------------------------------------


def test_the_readme_is_short_and_its_links_work_on_github():
    # What a newcomer reads in five minutes; the Quick start's two commands are checked by tests/test_project.py.
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    assert re.findall(r"^## (.+)$", text, re.MULTILINE)[:3] == [
        "Quick start",
        "Installing",
        "The workflow on your own camera",
    ]
    # Links into the repository (the site's Markdown sources, the picture, CONTRIBUTING, ...) are files that exist,
    # so GitHub shows them; every tutorial and reference page is linked.
    links = re.findall(r"\]\(((?:docs/|CONTRIBUTING|CITATION|CHANGELOG)[^)#]*)", text)
    for link in links:
        assert (ROOT / link).exists(), link
    assert "docs/images/before-after.png" in links
    for name in TUTORIALS:
        assert f"docs/tutorials/{name}.md" in links, name
    reference = re.findall(r"\]\(\.\./([a-z-]+\.md)\)", (DOCS / "reference" / "index.md").read_text())
    assert reference and all(f"docs/{page}" in links for page in reference), reference


def test_the_benchmark_figures_are_written_into_the_benchmarks_page(tmp_path):
    # benchmarks/run.py --write-docs puts what the run printed between the markers of docs/benchmarks.md, and
    # leaves the rest of the page as it was.
    run = runpy.run_path(str(ROOT / "benchmarks" / "run.py"))
    assert run["PAGE"] == DOCS / "benchmarks.md"
    page = tmp_path / "benchmarks.md"
    page.write_text(run["PAGE"].read_text())
    run["write_page"]("\n===== calibration =====\nnew figures\n", page)
    head, rest = page.read_text().split(run["START"])
    figures, tail = rest.split(run["END"])
    assert figures == "\n```text\n===== calibration =====\nnew figures\n```\n"
    before = run["PAGE"].read_text()
    assert before.startswith(head) and before.endswith(tail) and "Intel(R) Xeon(R) Processor" in before


@pytest.mark.slow
def test_the_readme_workflow_runs_on_the_simulator(tmp_path):
    # The five commands of "The workflow on your own camera", in order, on a simulated calibration run
    # (captures/) and a folder holding its target (scans/).
    section = README.read_text().split("## The workflow", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.DOTALL).group(1)
    commands = [line.split("#")[0].strip() for line in block.strip().splitlines()]
    workflow = ["inspect", "calibrate", "correct", "export-tuning", "report"]
    assert [command.split()[1] for command in commands] == workflow
    simulate = ["picamcal", "simulate", "--size", "320x240", "--out", "captures"]
    subprocess.run(simulate, cwd=tmp_path, check=True, capture_output=True)
    (tmp_path / "scans").mkdir()
    shutil.copy(tmp_path / "captures" / "target.dng", tmp_path / "scans" / "frame1.dng")
    for command in commands:
        result = subprocess.run(command, shell=True, cwd=tmp_path, capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, (command, result.stderr)
    assert (tmp_path / "corrected" / "frame1.tiff").exists() and (tmp_path / "report" / "index.html").exists()
    assert {p.name for p in (tmp_path / "tuning").iterdir()} == {"imx219_vc4.json", "imx219_pisp.json"}


def test_the_readme_picture_is_what_its_script_makes():
    # docs/images/before_after.py on the simulator, against the committed PNG: the same pixels within 2 DN of 8-bit
    # sRGB (numpy's and the BLAS's float rounding may move a value across a code's edge; nothing else varies).
    made = runpy.run_path(str(DOCS / "images" / "before_after.py"))["make_image"]()
    committed = np.asarray(Image.open(DOCS / "images" / "before-after.png").convert("RGB"))
    assert made.shape == committed.shape == (240, 656, 3)
    assert int(np.abs(made.astype(int) - committed).max()) <= 2


# --- the citation and the changelog -----------------------------------------------------------------------------


def test_citation_cites_picamcal_and_the_paper():
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    version = re.search(r'^version = "(.+)"', (ROOT / "pyproject.toml").read_text(), re.MULTILINE).group(1)
    assert citation["cff-version"] == "1.2.0" and citation["type"] == "software"
    assert citation["version"] == version and citation["license"] == "GPL-3.0-or-later"
    (paper,) = citation["references"]
    assert paper["doi"] == "10.5334/joh.20" and paper["journal"] == "Journal of Open Hardware"
    assert [author["family-names"] for author in paper["authors"]] == ["Bowman", "Vodenicharski", "Collins", "Stirling"]


def test_changelog_keeps_an_unreleased_section_and_the_current_version():
    text = (ROOT / "CHANGELOG.md").read_text()
    version = re.search(r'^version = "(.+)"', (ROOT / "pyproject.toml").read_text(), re.MULTILINE).group(1)
    headings = re.findall(r"^## \[(.+?)\]", text, re.MULTILINE)
    assert headings[0] == "Unreleased" and version in headings
    for section in re.findall(r"^### (.+)$", text, re.MULTILINE):
        assert section in {"Added", "Changed", "Deprecated", "Removed", "Fixed", "Security", "Known gaps"}, section


def test_every_tutorial_block_is_run_or_says_why_not():
    # A tutorial's commands run when the site is built ({commands}); a plain code block would not be checked.
    for name in TUTORIALS:
        text = (DOCS / "tutorials" / f"{name}.md").read_text()
        plain = re.findall(r"^```(bash|sh|console|python|py)\s*$", text, re.MULTILINE)
        assert not plain, f"tutorials/{name}.md: use {{commands}} (with :not-run: REASON where it cannot run)"
