"""The examples (examples/): what they need is what their extra installs, and without it they say
in one line what to install."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.helpers import load_module

ROOT = Path(__file__).resolve().parents[2]
tomllib = pytest.importorskip("tomllib")  # Python 3.11+


def load_example(name: str):
    return load_module(ROOT / "examples" / f"{name}.py", f"example_{name}")


def _name(requirement: str) -> str:
    return re.split(r"[\s\[<>=!~;]", requirement.strip(), maxsplit=1)[0].lower().replace("_", "-")


def test_the_rllib_extra_installs_what_rllib_needs_but_its_gymnasium_pin():
    """Every requirement of Ray's ``rllib`` extra is in gym_gridloc's ``rllib`` extra, Ray's
    ``tune`` extra (which ours requires), the core or the ``rl`` extra: all but the exact gymnasium
    pin, which the core's range covers."""
    from importlib import metadata

    try:
        ray_requires = metadata.requires("ray") or []
    except metadata.PackageNotFoundError:
        pytest.skip("ray is not installed (the sweep or rllib extra)")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    extras = project["optional-dependencies"]
    assert any(r.startswith("ray[tune]") for r in extras["rllib"])
    of_ray = {}
    for r in ray_requires:
        if m := re.search(r"""extra\s*==\s*["'](\w+)["']""", r):
            of_ray.setdefault(m.group(1), set()).add(_name(r))
    ours = {_name(r) for r in (*extras["rllib"], *project["dependencies"], *extras["rl"])}
    lacking = of_ray["rllib"] - of_ray.get("tune", set()) - ours - {"gymnasium"}
    assert not lacking, f"the rllib extra lacks {sorted(lacking)}"
    assert "dm-tree" in ours  # RLlib imports it as `tree`


def test_the_rllib_example_names_what_to_install_when_a_module_is_missing(monkeypatch, capsys):
    import sys

    example = load_example("rllib_ppo")
    monkeypatch.setitem(sys.modules, "tree", None)  # dm-tree not installed
    with pytest.raises(SystemExit) as exc:
        example.main(["--iterations", "1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "dm-tree" in err and ".[rl,rllib]" in err
