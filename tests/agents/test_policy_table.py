"""The one table of policies (``gym_gridloc_agents.registry.POLICIES``): ``make_policy`` is a
lookup in it, every policy refuses an option the table does not give it (a ``ValueError`` naming
the option and the accepted ones), the table's options are its constructors' own, and the command
line, the viewer and the docs read their names and options from it."""

from __future__ import annotations

import importlib.util
import inspect
import re
from pathlib import Path

import gymnasium as gym
import pytest

import gym_gridloc  # noqa: F401 - registers the environments
from gym_gridloc_agents.cli_args import build_parser
from gym_gridloc_agents.planners.base import keywords
from gym_gridloc_agents.planners.mcts import READINGS
from gym_gridloc_agents.policies import POLICIES, POLICY_NAMES, make_policy
from gym_gridloc_agents.registry import KINDS, PolicySpec, policy_spec

DOCS = Path(__file__).resolve().parents[2] / "docs"
#: An environment each policy runs on (central needs a "nothing" reading, optimal a noiseless model).
ENV_OF = {"central": ("RingSensor8x8-v0", {}), "optimal": ("DepthMaze-v0", {"size": 7, "map_seed": 0})}


def colour_grid():
    return gym.make("ColourGrid-v0").unwrapped.model


@pytest.mark.parametrize("name", POLICY_NAMES)
def test_every_policy_refuses_an_unknown_option_naming_it_and_the_accepted_ones(name):
    spec = POLICIES[name]
    with pytest.raises(ValueError) as caught:
        make_policy(name, colour_grid(), env_id="ColourGrid-v0", bogus=1)
    said = str(caught.value)
    assert f"policy {name!r} takes no option 'bogus'" in said
    if spec.options:
        assert f"its options: {', '.join(spec.options)}" in said
    else:
        assert "it takes no options" in said


@pytest.mark.parametrize("name", [n for n, s in POLICIES.items() if s.options])
def test_a_misspelled_option_is_refused_with_the_closest_one(name):
    option = POLICIES[name].options[0]
    with pytest.raises(ValueError, match=re.escape(f"did you mean {option!r}?")):
        make_policy(name, colour_grid(), env_id="ColourGrid-v0", **{option[:-1] + option[-1] * 2: 1})


def test_an_unknown_policy_is_refused_with_the_closest_one():
    with pytest.raises(ValueError, match="unknown policy 'expectimx' \\(did you mean 'expectimax'\\?\\); allowed: random"):
        policy_spec("expectimx")


def test_the_table_is_well_formed():
    assert POLICY_NAMES == tuple(POLICIES) and all(isinstance(s, PolicySpec) and s.name == n for n, s in POLICIES.items())
    for name, spec in POLICIES.items():
        assert spec.kind in KINDS, name
        assert callable(spec.load()), name
        assert len(set(spec.options)) == len(spec.options), name
        assert not (spec.expert and spec.kind == "learned"), name  # a warm start imitates what needs no model file
        assert not spec.values or spec.expert, name


def test_the_tables_options_are_the_constructors_own():
    """Each option the table gives is one its constructor takes, and the other way round (the
    seed and the referee's pose come from make_policy's own keywords)."""
    from gym_gridloc_agents.planners import CentralPolicy, ExpectimaxPolicy
    from gym_gridloc_agents.planners.optimal import OptimalPolicy
    from gym_gridloc_agents.planners.pomcp import PomcpPolicy

    own = {"seed", "pose"}
    assert set(POLICIES["central"].options) == keywords(CentralPolicy) - own
    assert set(POLICIES["expectimax"].options) == keywords(ExpectimaxPolicy) - own
    assert set(POLICIES["mcts"].options) == {"readings"}.union(*(keywords(c) - own for c in READINGS.values()))
    assert set(POLICIES["optimal"].options) == keywords(OptimalPolicy) - own
    assert set(POLICIES["pomcp"].options) == keywords(PomcpPolicy) - own
    for name in ("ppo", "distilled", "recurrent"):  # (the model file and the environment come from make_policy)
        build = inspect.signature(POLICIES[name].load()).parameters
        assert set(POLICIES[name].options) == set(build) - {"model", "context"}, name


@pytest.mark.parametrize("given, acts", [(None, True), (False, False), (True, True)])
def test_a_learned_policy_acts_as_its_model_says_unless_told(given, acts):
    """``deterministic``: the most probable action or a sampled one; not given, the model's
    metadata decides (the shipped ColourGrid model's: the most probable)."""
    options = {} if given is None else {"deterministic": given}
    policy = make_policy("ppo", colour_grid(), env_id="ColourGrid-v0", seed=0, **options)
    assert policy.deterministic is acts


def test_a_learned_policy_refuses_a_deterministic_that_is_not_a_bool():
    with pytest.raises(ValueError, match="deterministic must be true, false or None, got 'no'"):
        make_policy("ppo", colour_grid(), env_id="ColourGrid-v0", deterministic="no")


@pytest.mark.parametrize("readings, other", [("enumerate", "rollout"), ("sample", "prune")])
def test_mcts_refuses_the_options_of_its_other_readings(readings, other):
    with pytest.raises(ValueError, match=f"with readings={readings!r} takes no option {other!r}"):
        make_policy("mcts", colour_grid(), readings=readings, **{other: 1})


@pytest.mark.parametrize("name", POLICY_NAMES)
def test_make_policy_builds_each_line_of_the_table(name):
    if name == "pomcp" and importlib.util.find_spec("pomdp_py") is None:
        pytest.skip("needs pomdp_py (the planning extra)")
    env_id, kwargs = ENV_OF.get(name, ("ColourGrid-v0", {}))
    model = gym.make(env_id, **kwargs).unwrapped.model
    policy = make_policy(name, model, env_id=env_id, env_kwargs=kwargs, seed=0)
    assert policy.name == name and policy.model is model


def test_the_planners_threshold_is_the_environments_unless_given():
    model = colour_grid()
    kwargs = {"localise_threshold": 0.8}
    assert make_policy("expectimax", model, env_id="ColourGrid-v0", env_kwargs=kwargs).threshold == 0.8
    assert make_policy("expectimax", model, env_id="ColourGrid-v0", env_kwargs=kwargs, threshold=0.7).threshold == 0.7
    assert make_policy("expectimax", model).threshold == 0.9


def test_the_command_line_reads_the_table():
    parser = build_parser()
    bench = next(a for a in parser._subparsers._group_actions[0].choices["bench"]._actions if "--option" in a.option_strings)
    for name, spec in POLICIES.items():
        if spec.options:
            assert f"{name}: {', '.join(spec.options)}" in bench.help
    policies = next(a for a in parser._subparsers._group_actions[0].choices["bench"]._actions if "--policies" in a.option_strings)
    assert all(name in policies.help for name in POLICY_NAMES)


def test_the_planner_docs_name_every_option_of_the_table():
    page = (DOCS / "planners.md").read_text(encoding="utf-8")
    for name, spec in POLICIES.items():
        if spec.kind != "planner":
            continue
        section = page.split(f"### `{name}`", 1)[1].split("\n## ", 1)[0].split("\n### ", 1)[0]
        missing = [o for o in spec.options if o != "threshold" and f"`{o}`" not in section]
        assert not missing, (name, missing)
    assert "`threshold`" in page


def test_keywords_not_given_stay_not_given(monkeypatch):
    """A learned policy's model file is checked against the environment's keywords only when they
    are given: make_policy hands ``env_kwargs=None`` on as None, not as ``{}``."""
    from gym_gridloc_agents import learned

    seen = []
    monkeypatch.setattr(learned.PPOPolicy, "__init__", lambda self, model, **kw: seen.append(kw["env_kwargs"]))
    make_policy("ppo", colour_grid(), env_id="ColourGrid-v0")
    make_policy("ppo", colour_grid(), env_id="ColourGrid-v0", env_kwargs={"slip": 0.2})
    assert seen == [None, {"slip": 0.2}]
