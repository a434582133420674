"""The package as a whole: its layers, its import graph, its install names and its files."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Each package's folder: a file's path below its root (the repository, or agents/) is its import name.
PACKAGES = {"gym_gridloc": ROOT / "gym_gridloc", "gym_gridloc_agents": ROOT / "agents" / "gym_gridloc_agents"}
MAX_LINES = 400


def _modules() -> dict[str, Path]:
    out = {}
    for name, directory in PACKAGES.items():
        for f in directory.rglob("*.py"):
            parts = [name, *f.relative_to(directory).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = f
    return out


MODULES = _modules()


def _imports(module: str, path: Path) -> set[str]:
    """The package modules ``module`` imports, at the top or inside functions alike."""
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            for a in node.names:
                found.add(f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base)
    return {m for m in found if m in MODULES and m != module}


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles():
    assert _cycles(GRAPH) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_core_never_imports_the_agents():
    offenders = {m: sorted(deps) for m, deps in GRAPH.items() if m.startswith("gym_gridloc.")
                 and any(d.startswith("gym_gridloc_agents") for d in deps)}
    assert offenders == {}


def test_core_model_layer_imports_nothing_above_it():
    for m, deps in GRAPH.items():
        if m.startswith("gym_gridloc.core"):
            assert all(d.startswith("gym_gridloc.core") for d in deps), (m, deps)


def test_source_files_are_short_or_say_why():
    long = []
    for module, path in MODULES.items():
        n = len(path.read_text(encoding="utf-8").splitlines())
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
        if n > MAX_LINES and "longer than 400 lines" not in doc:
            long.append((module, n))
    assert long == []


def test_no_source_module_is_longer_than_400_lines():
    """Every module of both packages, docstring included, is at most :data:`MAX_LINES` lines: a
    module that grows past it is split by concept (no waiver)."""
    lengths = {module: len(path.read_text(encoding="utf-8").splitlines()) for module, path in MODULES.items()}
    assert {module: n for module, n in lengths.items() if n > MAX_LINES} == {}
    assert len(lengths) > 50 and max(lengths.values()) > MAX_LINES // 2  # (every module read)


@pytest.mark.parametrize("folder", ["tests", "scripts"])
def test_no_sys_path_edits(folder):
    pattern = re.compile(r"sys\.path\.(insert|append)|sys\.path\s*=")
    hits = [str(p.relative_to(ROOT)) for p in (ROOT / folder).rglob("*.py")
            if p.resolve() != Path(__file__).resolve() and pattern.search(p.read_text(encoding="utf-8"))]
    assert hits == []


def test_import_agents_from_outside_the_repository_finds_nothing_of_ours(tmp_path):
    code = (
        "import importlib.util, sys\n"
        "spec = importlib.util.find_spec('agents')\n"
        "print('none' if spec is None else spec.origin)\n"
        "import gym_gridloc_agents, gym_gridloc\n"
        "print(gym_gridloc_agents.__name__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.split()
    assert first == "none" or str(ROOT) not in first
    assert second == "gym_gridloc_agents"


def test_setuptools_builds_the_packages_without_warnings(tmp_path):
    """``build_py`` (what ``pip install``, ``pip wheel`` and ``python -m build`` run) on a copy of the
    sources: no "Package would be ignored" (the data folders ``models/`` and
    ``planners/fitted_leaves/`` are found as packages of their own) and no other setuptools warning;
    the data lands where the code looks for it, every module where its import name says."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        (src / name).write_bytes((ROOT / name).read_bytes())
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "_build")
    for folder in ("gym_gridloc", "agents"):
        shutil.copytree(ROOT / folder, src / folder, ignore=ignore)
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-W", "default", "-c", "from setuptools import setup; setup()",
                             "build_py", "--build-lib", str(out)], cwd=src, capture_output=True, text=True, timeout=120)
    log = result.stdout + result.stderr
    assert result.returncode == 0, log[-3000:]
    assert "would be ignored" not in log
    warnings = [line for line in log.splitlines() if re.search(r"warning", line, re.I)
                and "byte-compiling is disabled" not in line]  # (PYTHONDONTWRITEBYTECODE, not the config)
    assert warnings == [], "\n".join(warnings)
    agents = out / "gym_gridloc_agents"
    source = PACKAGES["gym_gridloc_agents"]
    assert sorted(p.name for p in (agents / "models").glob("*.zip")) == sorted(
        p.name for p in (source / "models").glob("*.zip")) != []
    assert sorted(p.name for p in (agents / "planners" / "fitted_leaves").glob("*.json")) == sorted(
        p.name for p in (source / "planners" / "fitted_leaves").glob("*.json")) != []
    assert (agents / "py.typed").is_file() and (out / "gym_gridloc" / "py.typed").is_file()
    assert (agents / "planners" / "leaves.py").is_file() and (agents / "viewer" / "app.py").is_file()
    built = {".".join(p.relative_to(out).with_suffix("").parts).removesuffix(".__init__") for p in out.rglob("*.py")}
    assert built == set(MODULES)


def test_agents_folder_holds_the_package_and_nothing_else():
    """The repository's ``agents/`` folder is a source root, like the repository itself: it holds
    ``gym_gridloc_agents/`` only (no ``agents/__init__.py``), so ``agents/<dotted path>.py`` is a
    module's import name."""
    assert sorted(p.name for p in (ROOT / "agents").iterdir() if p.name != "__pycache__") == ["gym_gridloc_agents"]
    for module, path in MODULES.items():
        root = ROOT / "agents" if module.startswith("gym_gridloc_agents") else ROOT
        assert ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__") == module


def test_setup_script_says_what_it_is_doing():
    """scripts/setup.sh prints one numbered line per stage and keeps pip quiet, torch pinned first."""
    text = (ROOT / "scripts" / "setup.sh").read_text(encoding="utf-8")
    stages = re.findall(r'^\s*(?:stage|echo)\b.*\[(\d)/(\d)\]', text, re.M)
    assert stages, "no numbered stage lines"
    (total,) = {int(n) for _, n in stages}
    assert sorted({int(i) for i, _ in stages}) == list(range(1, total + 1))
    pips = [line for line in text.splitlines() if "pip install" in line and not line.lstrip().startswith("#")]
    assert pips and all(" -q " in line for line in pips)
    assert text.index('"torch==2.13.0"') < text.index('-e ".[')


def test_citation_file_is_valid_cff_and_matches_the_package():
    """CITATION.cff: the Citation File Format 1.2.0's required keys and types, the package's
    version and licence."""
    yaml = pytest.importorskip("yaml")
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert cff["cff-version"] == "1.2.0"
    for key in ("message", "title"):
        assert isinstance(cff[key], str) and cff[key].strip()
    assert isinstance(cff["authors"], list) and cff["authors"]
    for author in cff["authors"]:  # a person (family-names) or an entity (name)
        assert isinstance(author, dict) and ({"name", "family-names"} & set(author)), author
    assert cff.get("type", "software") in ("software", "dataset")
    assert str(cff["version"]) == project["version"]
    assert cff["license"] == project["license"]
    allowed = {"cff-version", "message", "title", "authors", "type", "version", "license", "abstract", "keywords",
               "date-released", "doi", "url", "repository-code", "identifiers", "preferred-citation", "references",
               "commit", "contact", "license-url", "repository", "repository-artifact"}
    assert set(cff) <= allowed, set(cff) - allowed
