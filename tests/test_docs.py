"""The documentation: the site builds with warnings as errors, broken internal links fail that build,
the docstrings' examples (doctests) pass, and the guide's Python examples run.

The build needs the ``docs`` extra (sphinx, furo, myst-parser; ``scripts/setup.sh`` installs it):
without it those tests are skipped, saying so. The doctests and the guide's examples need only the
core install.
"""

from __future__ import annotations

import doctest
import importlib
import importlib.util
import os
import pkgutil
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

import gym_gridloc

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
BUILD_SECONDS = 120  # the build takes about 20 s on a busy 2-core machine; this is a hang guard

DOCS_DEPS = ("sphinx", "furo", "myst_parser")
missing = [m for m in DOCS_DEPS if importlib.util.find_spec(m) is None]
needs_sphinx = pytest.mark.skipif(
    bool(missing),
    reason=f"the docs extra is not installed (missing {', '.join(missing)}): pip install -e '.[docs]'",
)


def sphinx_build(srcdir: Path, outdir: Path, *args: str, confdir: Path | None = None) -> subprocess.CompletedProcess:
    """``sphinx-build -W --keep-going -n`` (warnings are errors, every internal reference checked)."""
    cmd = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-n", "-q", "-E",
           "-d", str(outdir / ".doctrees"), *args]
    if confdir is not None:
        cmd += ["-c", str(confdir)]
    cmd += [str(srcdir), str(outdir / "html")]
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=BUILD_SECONDS, env=env)


# -- the site ----------------------------------------------------------------------------------------------
@needs_sphinx
def test_docs_build_without_warnings(tmp_path):
    start = time.perf_counter()
    result = sphinx_build(DOCS, tmp_path)
    seconds = time.perf_counter() - start
    assert result.returncode == 0, f"sphinx-build -W failed:\n{result.stdout}\n{result.stderr}"
    html = tmp_path / "html"
    for page in ("index", "getting-started", "environments", "results", "api/filters", "changelog"):
        assert (html / f"{page}.html").is_file(), page
    # one generated page per registered environment, with the registry's and the instance's facts
    import gymnasium as gym

    for env_id in gym_gridloc.ENV_IDS:
        spec = gym.spec(env_id)
        name = spec.entry_point.split(":")[0].rsplit(".", 1)[-1]
        text = (html / "envs" / f"{name}.html").read_text(encoding="utf-8")
        assert env_id in text and str(gym.make(env_id).action_space) in text
        assert f'src="../_images/episode_{env_id}.png"' in text, f"no picture on {env_id}'s page"
        assert (ROOT / "results" / f"episode_{env_id}.png").stat().st_size < 300_000
    # the figures from results/ are in the site (copied by the build, not committed twice)
    images = {p.name for p in (html / "_images").iterdir()}
    assert {"episode.png", "bench_WindyMaze-v0.png", "compare_filters.png"} <= images
    assert seconds < BUILD_SECONDS


@needs_sphinx
def test_broken_internal_links_fail_the_build(tmp_path):
    """A missing page, a missing heading anchor and an unknown API name each fail a -W build."""
    src = tmp_path / "src"
    src.mkdir()
    (src / "index.md").write_text(
        "# Broken\n\n"
        "[a page that does not exist](no-such-page.md)\n\n"
        "[a heading that does not exist](#no-such-heading)\n\n"
        "{py:func}`gym_gridloc.no_such_function`\n\n"
        "```{toctree}\n:hidden:\n:glob:\n\nenvs/*\n```\n",
        encoding="utf-8",
    )
    result = sphinx_build(src, tmp_path / "out", confdir=DOCS)
    assert result.returncode != 0
    log = result.stderr
    assert "no-such-page" in log, log
    assert "no-such-heading" in log, log
    assert "gym_gridloc.no_such_function" in log, log


# -- doctests in the docstrings ------------------------------------------------------------------------
def _modules(package) -> list[str]:
    return [m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + ".")]


def _agents_modules() -> list[str]:
    try:
        import gym_gridloc_agents
    except ImportError:
        return []
    return _modules(gym_gridloc_agents)


@pytest.mark.parametrize("module_name", ["gym_gridloc", *_modules(gym_gridloc), *_agents_modules()])
def test_doctests(module_name):
    try:
        module = importlib.import_module(module_name)
    except ImportError as e:  # an optional dependency (numba, stable-baselines3, ...)
        pytest.skip(f"{module_name} needs an optional dependency: {e}")
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    report: list[str] = []
    for test in finder.find(module):
        runner.run(test, out=report.append)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, "".join(report)


# -- the guide's examples ------------------------------------------------------------------------------
GUIDE_PAGES = ("index.md", "getting-started.md", "environments.md", "filtering.md", "inference.md")


@pytest.mark.parametrize("page", GUIDE_PAGES)
def test_guide_examples_run(page, tmp_path, monkeypatch):
    """Every ```python block of the page runs, in order, in one namespace (as a reader would paste them)."""
    monkeypatch.chdir(tmp_path)
    blocks = re.findall(r"^```python\n(.*?)^```", (DOCS / page).read_text(encoding="utf-8"), re.M | re.S)
    assert blocks, f"{page} has no Python example"
    namespace: dict = {"__name__": "__docs__"}
    for i, code in enumerate(blocks):
        try:
            exec(compile(code, f"{page}, example {i + 1}", "exec"), namespace)
        except Exception as e:
            raise AssertionError(f"{page}, example {i + 1} fails:\n{code}") from e


def test_every_markdown_link_works_on_github_too():
    """GitHub renders the .md pages too: a Markdown link's target is a web address, an anchor
    (``#heading``) or a file that exists beside the page (``planners.md#anchor``), never a MyST
    label, which only Sphinx resolves (``{ref}`label``` is the way to a label).  (The pages of
    docs/envs/ are written when the site is built, by docs/_ext/gridloc_envs.py.)"""
    pages = sorted(DOCS.glob("*.md")) + [p for p in sorted(ROOT.glob("*.md")) if p.name != "README.md"]
    dead = []
    for page in pages:
        text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.M | re.S)  # not in code blocks
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target) or target.startswith(("#", "envs/")):
                continue
            if not (page.parent / target.split("#")[0]).exists():
                dead.append(f"{page.relative_to(ROOT)}: ({target})")
    assert not dead, dead


def test_the_pages_agree_with_the_code():
    """What set-up installs (every extra of pyproject.toml), how many policies there are and their
    names (``POLICY_NAMES``), and what ``flatten=True`` holds for a bit reading (the bits, not a
    one-hot code), as the code has them."""
    tomllib = pytest.importorskip("tomllib")
    extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"])
    setup = (ROOT / "scripts" / "setup.sh").read_text(encoding="utf-8")
    assert set(re.search(r'-e "\.\[([^\]]+)\]"', setup).group(1).split(",")) == extras
    said = re.search(r"`scripts/setup.sh` makes `.venv`(.*?)\n\n", (DOCS / "getting-started.md").read_text(encoding="utf-8"), re.S)
    assert set(re.findall(r"`(\w+)`", said.group(1))) >= extras
    dev = next(line for line in (DOCS / "development.md").read_text(encoding="utf-8").splitlines() if "scripts/setup.sh " in line)
    assert all(re.search(rf"\b{e}\b", dev) for e in extras), dev

    import gymnasium as gym

    env = gym_gridloc.HMMBeliefWrapper(gym.make("WindyMaze-v0"), flatten=True)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.shape[0] == 4 + 6 * 7 and set(obs[:4]) <= {0.0, 1.0}  # the four bits, then the belief
    assert "the bits as they are for a `MultiBinary` one" in (DOCS / "filtering.md").read_text(encoding="utf-8")
    assert "the bits as they\nare" in (DOCS / "getting-started.md").read_text(encoding="utf-8")

    policies = pytest.importorskip("gym_gridloc_agents.policies")
    words = {10: "ten", 11: "eleven", 12: "twelve"}
    names = policies.POLICY_NAMES
    assert f"has {words[len(names)]}\npolicies" in (DOCS / "training.md").read_text(encoding="utf-8")
    row = next(line for line in (DOCS / "viewer.md").read_text(encoding="utf-8").splitlines() if line.startswith("| `--policy NAME`"))
    assert tuple(re.findall(r"`(\w+)`", row.split(":", 1)[1].split("(see")[0])) == names
