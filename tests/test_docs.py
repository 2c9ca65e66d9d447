"""The docs site builds strictly (a broken link or a missing API reference fails it), its
images are small, and its architecture page names every module of the package."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
HAVE_MKDOCS = all(importlib.util.find_spec(m) for m in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers"))
needs_mkdocs = pytest.mark.skipif(not HAVE_MKDOCS, reason='mkdocs, mkdocs-material or mkdocstrings[python] is not '
                                  'installed: pip install -e ".[docs]"')


def build(config: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
                          cwd=config.parent, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})


@needs_mkdocs
def test_the_site_builds_strictly_within_a_minute(tmp_path):
    start = time.perf_counter()
    done = build(ROOT / "mkdocs.yml", tmp_path / "site")
    seconds = time.perf_counter() - start
    assert done.returncode == 0, done.stdout + done.stderr
    assert seconds < 60, f"mkdocs build took {seconds:.0f} s"
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    for name in ("hybridfit.fit", "hybridfit.FitResult", "hybridfit.HybridEstimator", "hybridfit.HandModel",
                 "hybridfit.Objective", "hybridfit.Optimizer", "hybridfit.Task", "hybridfit.Problem",
                 "hybridfit.registry.create", "hybridfit.testing.check_optimizer", "hybridfit.study.run_study"):
        assert f'id="{name}"' in api, name
    roles = re.findall(r":(?:func|class|mod|meth|attr|data|exc):`", api)
    assert roles == [], f"{len(roles)} raw reST roles on the API page"
    assert 'href="#hybridfit.fitting.calibrate.calibrate"><code>' in api  # a role, now a link
    signature = api[api.index('id="hybridfit.fit"'):].split("</pre>", 1)[0]
    assert signature.count("\n") > 10, "long signatures are formatted one parameter a line (ruff)"
    cli = (tmp_path / "site" / "cli" / "index.html").read_text()
    from hybridfit.cli import build_parser

    for command in build_parser()._subparsers._group_actions[0].choices:
        assert f"usage: hybridfit {command}" in cli, command


@pytest.fixture()
def small_site(tmp_path):
    """The real mkdocs.yml (theme, plugins, strict validation) on two small pages."""
    import yaml

    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    config.pop("nav")
    config["hooks"] = [str(ROOT / h) for h in config.get("hooks", [])]
    python = config["plugins"][2]["mkdocstrings"]["handlers"]["python"]["options"]
    python["extensions"] = [str(ROOT / e) for e in python["extensions"]]
    (tmp_path / "docs").mkdir()
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump(config))
    (tmp_path / "docs" / "index.md").write_text("# Home\n\nThe [API](api.md#hybridfit.fit).\n")
    (tmp_path / "docs" / "api.md").write_text("# API\n\n::: hybridfit.fit\n")
    return tmp_path


@needs_mkdocs
@pytest.mark.parametrize("page, injected, message", [
    (None, "", None),  # the control: the small site builds
    ("index.md", "A [broken link](no-such-page.md).", "no-such-page.md"),
    ("index.md", "A [broken anchor](api.md#no-such-heading).", "no-such-heading"),
    ("api.md", "::: hybridfit.no_such_function", "no_such_function"),
])
def test_a_broken_link_or_a_missing_reference_fails_the_build(small_site, page, injected, message):
    if page:
        path = small_site / "docs" / page
        path.write_text(path.read_text() + "\n" + injected + "\n")
    done = build(small_site / "mkdocs.yml", small_site / "site")
    if message is None:
        assert done.returncode == 0, done.stdout + done.stderr
    else:
        assert done.returncode != 0 and message in done.stdout + done.stderr, done.stdout + done.stderr


def test_every_image_is_small_and_shown():
    pages = "".join(p.read_text() for p in (ROOT / "docs").glob("*.md")) + (ROOT / "README.md").read_text()
    images = sorted((ROOT / "docs" / "images").glob("*.png"))
    assert images
    for image in images:
        assert image.stat().st_size < 300_000, image.name
        assert f"images/{image.name}" in pages, f"{image.name} is on no page"


def test_the_architecture_tree_names_every_module():
    """Every module of the package (the CLI's subcommands aside) is named in the folder tree
    of docs/architecture.md."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    tree = re.search(r"```\n(hybridfit/.*?)```", text, re.S).group(1)
    words = set(re.findall(r"[a-z_0-9]+", tree.lower()))
    modules = [p for p in (ROOT / "hybridfit").rglob("*.py")
               if p.stem not in ("__init__", "__main__") and "cli" not in p.parts]
    missing = sorted(str(p.relative_to(ROOT)) for p in modules if p.stem not in words)
    assert not missing, f"modules missing from docs/architecture.md's folder tree: {missing}"
    packages = sorted({p.parent.name for p in modules} - {"hybridfit"})
    assert all(f"{name}/" in tree for name in packages)


def test_the_getting_started_python_examples_run(tmp_path):
    """The page's first three Python blocks (a fit, plugins by name, stress data) run as one script."""
    page = (ROOT / "docs" / "getting-started.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", page, re.S)[:3]
    script = "".join(blocks) + "\nassert result.evaluations.tolist() == [8281] * 20 and joints.shape == (20, 21, 3)\n"
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr


def test_the_docs_sections_that_docstrings_point_to_exist():
    """A docstring that moved its figures to the docs names the page and section; both exist."""
    pointers = []
    for path in [*(ROOT / "hybridfit").rglob("*.py"), *(ROOT / "plugins").rglob("*.py")]:
        text = re.sub(r"\n\s*(#:?)?\s*", " ", path.read_text()).replace('\\"', '"')
        pointers += [(path.name, page, section)
                     for page, section in re.findall(r"""docs' ([a-z-]+) page, section "([^"]+)\"""", text)]
    assert len(pointers) >= 5, pointers
    for module, page, section in pointers:
        headings = re.findall(r"^#+ (.+)$", (ROOT / "docs" / f"{page}.md").read_text(), re.M)
        assert section in headings, f"{module} points to docs/{page}.md, section {section!r}, which is not a heading"


def test_rest_roles_become_references_relative_to_their_module():
    import importlib.util as iu

    spec = iu.spec_from_file_location("rest_roles", ROOT / "docs_hooks" / "rest_roles.py")
    roles = iu.module_from_spec(spec)
    spec.loader.exec_module(roles)
    module = "hybridfit.datasets.folder"
    assert roles.target_of("~hybridfit.errors.HybridfitError", module) == ("hybridfit.errors.HybridfitError", "HybridfitError")
    assert roles.target_of(".images", module) == ("hybridfit.datasets.images", "images")
    assert roles.target_of(".images", "hybridfit.datasets", package=True)[0] == "hybridfit.datasets.images"
    assert roles.target_of("write_dataset", module) == ("hybridfit.datasets.folder.write_dataset", "write_dataset")
    assert roles.target_of("the fit <hybridfit.fit>", module) == ("hybridfit.fit", "the fit")
    out = roles.roles_to_links("See :func:`~hybridfit.fit` and :class:`a <x.B>`.", module)
    assert out == ('See <autoref identifier="hybridfit.fit" optional><code>fit</code></autoref> and '
                   '<autoref identifier="x.B" optional><code>a</code></autoref>.')


def test_the_blender_import_gives_the_camera_view_axes_and_frame_rate():
    """The BVH is in camera axes (x right, y down, z forward): Blender's importer needs forward
    Z and up -Y to show it as the camera saw it, and update_scene_fps for the file's rate."""
    page = " ".join((ROOT / "docs" / "data.md").read_text().split())
    for needed in ("global_scale=0.001", "axis_forward='Z'", "axis_up='-Y'", "update_scene_fps=True"):
        assert needed in page, needed
    # the axes as Blender's axis_conversion applies them (to forward Y, up Z): camera -> Blender
    forward, up = np.array([0, 0, 1]), np.array([0, -1, 0])  # the file's axes named forward and up
    R = np.stack([np.cross(forward, up), forward, up])  # rows: Blender X, Y, Z in file axes
    assert np.linalg.det(R) == 1  # a rotation
    assert (R @ [1, 0, 0]).tolist() == [1, 0, 0]  # camera right = Blender X (right in the front view)
    assert (R @ [0, -1, 0]).tolist() == [0, 0, 1]  # image up = Blender Z
    assert (R @ [0, 0, 1]).tolist() == [0, 1, 0]  # into the scene = Blender Y (away, in the front view)


@pytest.mark.parametrize("image", ["stepwise_vs_joint_quick_success.png", "stepwise_vs_joint_quick_per_joint.png"])
def test_the_study_figures_show_the_studys_variants_as_they_are_named_now(image):
    """The docs' study figures are the README's quick study's: each variant it runs, by its
    current name, is in the figure (stale copies showed 7 rows and an old variant name)."""
    import json

    from PIL import Image

    from hybridfit.study import load_spec
    from hybridfit.study.expand import expand
    from hybridfit.study.plots import VARIANTS_KEY

    text = Image.open(ROOT / "docs" / "images" / image).text
    assert VARIANTS_KEY in text, f"{image} was not written by this hybridfit's study plots: re-run the quick study"
    drawn = json.loads(text[VARIANTS_KEY])
    variants = [v.name for v in expand(load_spec(ROOT / "studies" / "stepwise_vs_joint.toml", quick=True))]
    assert [d for d in drawn if d in variants] == variants, (drawn, variants)
