"""One owner per concept: the wrapper serves the environment's posterior (one filter
step per environment step), one observation builder for the wrapper, the vector env and the
learned policies, one KEY=VALUE reader, the planners stop where the referee does; one place each
for integer checks, kidnap mixing and entropy (the sources are read: a copy fails here)."""

from __future__ import annotations

import ast
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import HMMBeliefWrapper, engine, referee
from gym_gridloc.filter import ForwardFilter
from gym_gridloc.observation import BeliefObservation

ENV_IDS = ("ColourGrid-v0", "WindyMaze-v0", "RingSensor8x8-v0", "DepthMaze-v0")


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_wrapper_serves_the_environments_posterior(env_id):
    env = HMMBeliefWrapper(gym.make(env_id), full_state=True)
    obs, _ = env.reset(seed=0)
    inner = env.unwrapped
    assert env.filter is inner.exact_filter  # one belief: the referee's object
    rng = np.random.default_rng(0)
    for _ in range(15):
        obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        assert env.filter is inner.exact_filter
        np.testing.assert_array_equal(obs["belief"], np.minimum(inner.exact_filter.full_belief, 1).astype(np.float32))
        if terminated or truncated:
            obs, _ = env.reset()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_one_filter_step_per_environment_step(env_id, monkeypatch):
    """The belief is filtered once per environment step, in the step of the batch (the single
    environment is its N = 1 view); the wrapper filters nothing of its own."""
    from gym_gridloc.batch import Batch

    env = HMMBeliefWrapper(gym.make(env_id))
    env.reset(seed=1)
    calls, filtered = [], []
    real, real_filter = Batch.advance, ForwardFilter.step
    monkeypatch.setattr(Batch, "advance", lambda self, *a, **k: (calls.append(1), real(self, *a, **k))[1])
    monkeypatch.setattr(ForwardFilter, "step", lambda self, *a, **k: (filtered.append(1), real_filter(self, *a, **k))[1])
    steps = 0
    for a in [0, 1, 2, 1, 0, 2, 2, 1]:
        _, _, terminated, truncated, _ = env.step(a)
        steps += 1
        if terminated or truncated:
            break
    assert len(calls) == steps and not filtered


def test_another_model_or_particles_keep_a_filter_of_their_own():
    env = gym.make("ColourGrid-v0")
    other = gym_gridloc.colour_grid_model(slip=0.3)
    mismatched = HMMBeliefWrapper(env, model=other, on_impossible="reset")
    mismatched.reset(seed=0)
    assert mismatched.filter is not env.unwrapped.exact_filter and mismatched.filter.model is other
    particles = HMMBeliefWrapper(gym.make("ColourGrid-v0"), belief="particles", n_particles=100)
    particles.reset(seed=0)
    assert particles.filter is not particles.unwrapped.exact_filter
    same = HMMBeliefWrapper(env, model=env.unwrapped.model)  # the environment's model, given: served too
    same.reset(seed=0)
    assert same.filter is env.unwrapped.exact_filter


def test_a_redrawn_map_is_served_too():
    env = HMMBeliefWrapper(gym.make("WindyMaze-v0", size=9, new_map_each_reset=True))
    env.reset(seed=0)
    first = env.unwrapped.model
    env.reset(seed=1)
    assert env.unwrapped.model is not first and env.model is env.unwrapped.model
    assert env.filter is env.unwrapped.exact_filter


@pytest.mark.parametrize("options", [{}, {"flatten": True}, {"full_state": True}, {"map": True, "lookahead": 1},
                                     {"flatten": True, "map": True, "lookahead": 2}])
@pytest.mark.parametrize("env_id", ["ColourGrid-v0", "DepthMaze-v0"])
def test_one_observation_builder_for_the_wrapper_the_vector_env_and_the_policies(env_id, options):
    from gym_gridloc_agents.policies import PPOPolicy

    vec = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", **options)
    single = HMMBeliefWrapper(gym.make(env_id), **options)
    vobs, _ = vec.reset(seed=4)
    sobs, _ = single.reset(seed=4)
    model = single.unwrapped.model
    policy = PPOPolicy.__new__(PPOPolicy)  # the encoding only (no model file)
    policy.model, policy.wrapper, policy._builder = model, dict(options), None
    policy.n_actions = model.n_actions
    for a in [1, 0, 2, 1]:
        raw = model.sensor.to_observation(single.unwrapped.last_reading)
        mine = policy.encode(raw, single.filter.full_belief)
        if isinstance(sobs, dict):
            for k in sobs:
                np.testing.assert_array_equal(np.asarray(sobs[k]), np.asarray(vobs[k][0]))
                np.testing.assert_array_equal(np.asarray(sobs[k]), np.asarray(mine[k]))
        else:
            np.testing.assert_array_equal(sobs, vobs[0])
            np.testing.assert_array_equal(sobs, mine)
        assert policy.observation_options == single.builder.options
        sobs, *_ = single.step(a)
        vobs, *_ = vec.step(np.array([a]))


def test_the_builder_checks_its_options():
    model = gym_gridloc.colour_grid_model()
    with pytest.raises(TypeError, match="flatten must be True or False"):
        BeliefObservation(model, flatten="yes")
    with pytest.raises(ValueError, match="lookahead must be 0, 1 or 2"):
        BeliefObservation(model, lookahead=3)
    assert BeliefObservation(model, flatten=True).space == HMMBeliefWrapper(gym.make("ColourGrid-v0"), flatten=True).observation_space


def test_the_referees_test_is_pose_aware():
    b = np.zeros((2, 4, 3, 3))
    b[0, :, 1, 1] = 0.25  # sure of the position, not of the heading
    b[1, 2, 0, 0] = 1.0
    np.testing.assert_array_equal(referee.localised(b, 0.9), [True, True])
    np.testing.assert_array_equal(referee.localised(b, 0.9, pose=True), [False, True])
    np.testing.assert_allclose(referee.confidences(b, pose=True), [0.25, 1.0])


def test_the_planners_stop_on_the_pose_where_the_referee_does():
    from gym_gridloc_agents.policies import make_policy

    env = HMMBeliefWrapper(gym.make("DepthMaze-v0"))
    env.reset(seed=0)
    model = env.unwrapped.model
    assert env.unwrapped.referee_pose
    planner = make_policy("expectimax", model, env_id="DepthMaze-v0", seed=0, pose=True)
    assert planner.ops.pose
    b = np.zeros(model.belief_shape)
    r, c = (int(v) for v in model.grid.free_cells[0])
    b[:, r, c] = 0.25  # localised on the position, not on the pose: the environment goes on
    assert not planner.ops.localised(b[None])[0]
    assert make_policy("expectimax", model, env_id="DepthMaze-v0", seed=0).ops.localised(b[None])[0]


def test_kidnapping_mixed_in_one_place():
    model = gym_gridloc.windy_maze_model().with_kidnapping(0.1)
    assert engine.kidnapped(model, 0.5) == pytest.approx(0.9 * 0.5 + 0.1 / model.n_states)
    assert engine.kidnapped(gym_gridloc.windy_maze_model(), 0.5) == 0.5


def test_one_key_value_reader_for_bench_view_and_sweep():
    from gym_gridloc_agents.evaluation.bench_command import _key_values
    from gym_gridloc_agents.sweeps.sweep_spec import parse_grid
    from gym_gridloc_agents.values import key_values, parse_value
    from gym_gridloc_agents.viewer.args import parse_kw

    items = ["slip=1e-4", "size=16,16", "new_map_each_reset=true", "map_seed=3", "dynamics=passive", "layout=none"]
    want = {"slip": 0.0001, "size": (16, 16), "new_map_each_reset": True, "map_seed": 3, "dynamics": "passive",
            "layout": None}
    assert key_values(items, "--kw") == want
    assert _key_values(items, "--env-kwarg") == want
    assert parse_kw(items) == want
    grid = parse_grid(["env_kwargs.slip=1e-4,0.2", "env_kwargs.map_seed=3,4"])
    assert grid["env_kwargs.slip"] == [0.0001, 0.2] and grid["env_kwargs.map_seed"] == [3, 4]
    assert parse_value("[16, 16]") == [16, 16] and parse_value("2.5e3") == 2500.0 and parse_value("-3") == -3


def test_one_policy_table():
    from gym_gridloc_agents.evaluation import bench
    from gym_gridloc_agents import policies

    from gym_gridloc_agents import loading, registry
    from gym_gridloc_agents.evaluation import suite
    from gym_gridloc_agents.planners import PLANNER_NAMES

    assert policies.POLICIES is registry.POLICIES and policies.POLICY_NAMES == tuple(policies.POLICIES)
    assert set(policies.LEARNED_POLICIES) == set(policies.LEARNED_NAMES) == set(bench.LEARNED) == set(suite.LEARNED)
    assert loading.METHODS == policies.LEARNED_NAMES
    assert set(bench.PLANNERS) == {n for n, spec in policies.POLICIES.items() if spec.kind == "planner"}
    assert set(PLANNER_NAMES) == {n for n, spec in policies.POLICIES.items() if spec.values}
    assert bench.DEFAULT_POLICIES == policies.DEFAULT_POLICIES


# -- one owner each: integer checks, kidnap mixing, entropy (checked on the source) ------------------
ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted([*(ROOT / "gym_gridloc").rglob("*.py"), *(ROOT / "agents" / "gym_gridloc_agents").rglob("*.py")])


def _name(node: ast.AST) -> str:
    """``np.integer`` -> ``integer``, ``int`` -> ``int`` (the last part of a dotted name)."""
    return node.attr if isinstance(node, ast.Attribute) else node.id if isinstance(node, ast.Name) else ""


def _where(path: Path, node: ast.AST) -> str:
    return f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)[:100]}"


def _found(check, owners: set[str]) -> list[str]:
    """What ``check(path, node)`` flags in the package sources, the owners' files left out."""
    out = []
    for path in SOURCES:
        if path.relative_to(ROOT).as_posix() in owners:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if check(node):
                out.append(_where(path, node))
    return out


def _hand_rolled_integer_check(node: ast.AST) -> bool:
    """``isinstance(x, int)`` / ``(int, np.integer)`` / ``numbers.Integral`` (not a number test
    that lets floats in too), ``np.issubdtype(..., np.integer)``, ``int(x) != x``, ``a == np.round(a)``,
    ``operator.index``."""
    if isinstance(node, ast.Call) and _name(node.func) == "isinstance" and len(node.args) == 2:
        t = node.args[1]
        names = {_name(e) for e in (t.elts if isinstance(t, ast.Tuple) else [t])}
        return bool(names & {"int", "Integral", "integer"}) and not names & {"float", "Real", "floating", "str", "Number"}
    if isinstance(node, ast.Call) and _name(node.func) == "issubdtype":
        return any(_name(a) in ("integer", "int64") for a in node.args[1:])
    if isinstance(node, ast.Attribute) and node.attr == "index" and _name(node.value) == "operator":
        return True
    if isinstance(node, ast.Compare) and len(node.ops) == 1 and isinstance(node.ops[0], (ast.Eq, ast.NotEq)):
        sides = [node.left, node.comparators[0]]
        inner = [ast.dump(s.args[0]) for s in sides if isinstance(s, ast.Call) and _name(s.func) in ("int", "round") and s.args]
        bare = [ast.dump(s) for s in sides] + [ast.dump(s.args[0]) for s in sides if isinstance(s, ast.Call) and _name(s.func) == "float" and s.args]
        return any(i in bare for i in inner)
    return False


def test_integer_checks_in_one_place():
    """Every integer check calls ``gym_gridloc.core.validation`` (``is_int``, ``check_int``,
    ``whole_numbers``): no other module tests for an integer type or a whole value by hand."""
    assert _found(_hand_rolled_integer_check, {"gym_gridloc/core/validation.py"}) == []
    # (the check itself sees the forms it forbids)
    for text in ("isinstance(n, (int, np.integer))", "isinstance(n, numbers.Integral)", "int(n) != n", "float(v) != int(v)",
                 "np.all(a == np.round(a))", "np.issubdtype(a.dtype, np.integer)", "operator.index(n)"):
        assert any(_hand_rolled_integer_check(n) for n in ast.walk(ast.parse(text))), text
    assert not any(_hand_rolled_integer_check(n) for n in ast.walk(ast.parse("isinstance(v, (int, float))")))


def test_the_integer_owner():
    from gym_gridloc.core.validation import check_int, is_int, whole_numbers

    assert is_int(np.int64(3)) and not is_int(True) and not is_int(np.bool_(True)) and not is_int(3.0)
    assert check_int("n", 3.0, whole=True) == 3 and check_int("a", np.array(2), 0, 3, whole=True) == 2
    with pytest.raises(ValueError, match=r"^n must be a whole number, got 2\.5"):
        check_int("n", 2.5, whole=True)
    with pytest.raises(TypeError, match=r"^n must be an integer, got 'x'"):
        check_int("n", "x", whole=True)
    with pytest.raises(ValueError, match=r"^num_envs must be a positive integer, got True"):
        check_int("num_envs", True, what="a positive integer", error=ValueError)
    assert whole_numbers(np.array([1.0, 2.0])) and whole_numbers(np.array([1, 2]))
    assert not whole_numbers(np.array([1.5])) and not whole_numbers(np.array([np.inf])) and not whole_numbers(np.array([True]))


def _kidnap_arithmetic(tree: ast.AST):
    """Arithmetic on a kidnap probability (``model.kidnap_prob``, or a name bound to it)."""
    bound = {t.id for n in ast.walk(tree) if isinstance(n, ast.Assign) and _name(n.value) == "kidnap_prob"
             for t in n.targets if isinstance(t, ast.Name)}

    def kidnap(e: ast.AST) -> bool:
        return (isinstance(e, ast.Attribute) and e.attr == "kidnap_prob") or (isinstance(e, ast.Name) and e.id in bound)

    return [n for n in ast.walk(tree) if isinstance(n, (ast.BinOp, ast.AugAssign))
            and any(kidnap(e) for e in ([n.left, n.right] if isinstance(n, ast.BinOp) else [n.value]))]


def test_no_other_module_mixes_kidnapping():
    """Kidnap mixing is the engine's (``kidnapped``, and its dense matrix ``transition_matrix``): no
    other module computes with a kidnap probability."""
    found = []
    for path in SOURCES:
        if path.relative_to(ROOT).as_posix() != "gym_gridloc/engine.py":
            found += [_where(path, n) for n in _kidnap_arithmetic(ast.parse(path.read_text(encoding="utf-8")))]
    assert found == []
    assert _kidnap_arithmetic(ast.parse("k = model.kidnap_prob\nm = (1.0 - k) * m + k / S"))  # the check sees a copy
    assert not hasattr(gym_gridloc.GridModel, "transition_matrix")
    model = gym_gridloc.windy_maze_model().with_kidnapping(0.1)
    dense = engine.transition_matrix(model, 1).toarray()
    plain = engine.transition_matrix(gym_gridloc.windy_maze_model(), 1).toarray()
    np.testing.assert_array_equal(dense, engine.kidnapped(model, plain))
    np.testing.assert_allclose(dense.sum(axis=1), 1.0, rtol=0, atol=1e-12)


def _times_a_log(node: ast.AST) -> bool:
    """``p * np.log2(...)`` (or ``np.log``, either side): an entropy's terms."""
    return isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult) and any(
        isinstance(e, ast.Call) and isinstance(e.func, ast.Attribute) and e.func.attr in ("log", "log2", "log10")
        and _name(e.func.value) == "np" for e in (node.left, node.right))


def test_entropy_in_one_place():
    """The one belief entropy is ``referee.entropy``, its terms ``core.sensors.xlogx`` (the
    lookahead's expected entropies use them too): no other module writes ``p log p``."""
    assert _found(_times_a_log, {"gym_gridloc/core/sensors.py"}) == []
    assert any(_times_a_log(n) for n in ast.walk(ast.parse("h = -(p * np.log2(np.where(p > 0, p, 1.0))).sum()")))
    from gym_gridloc_agents.planners.ops import BeliefOps

    model = gym.make("DepthMaze-v0").unwrapped.model  # layered: the position entropy sums the headings out
    rng = np.random.default_rng(0)
    b = rng.random((5, *model.belief_shape)) * model.state_mask
    b /= b.reshape(5, -1).sum(axis=1)[:, None, None, None]
    np.testing.assert_array_equal(BeliefOps(model, 0.9).entropy(b), referee.entropy(b.sum(axis=1).reshape(5, -1)))


def _times_a_likelihood(node: ast.AST) -> bool:
    """``x * lik[z]`` (``ops.lik``, ``likelihood_table``): a Bayes update written inline."""
    return isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult) and any(
        isinstance(e, ast.Subscript) and _name(e.value) in ("lik", "likelihood_table") for e in (node.left, node.right))


def test_one_bayes_update():
    """The belief MDP's Bayes update (``Lookahead.update``: the prediction times the reading's
    likelihood, normalised) is the planners' one (``BeliefOps.update``) and the engine's numbers;
    no module but the engine's (its step, compiled or not, dense or sparse) and the belief MDP's multiplies by
    likelihoods inline."""
    from gym_gridloc.lookahead import Lookahead
    from gym_gridloc_agents.planners.ops import BeliefOps

    owners = {"gym_gridloc/lookahead.py", "gym_gridloc/derived.py", "gym_gridloc/_numba_filter.py", "gym_gridloc/_numba_sparse.py"}
    assert _found(_times_a_likelihood, owners) == []
    assert _times_a_likelihood(ast.parse("post = preds[a] * self.ops.lik[z]").body[0].value)
    for model in (gym_gridloc.ring_sensor_model((5, 5), dynamics="passive"), gym.make("DepthMaze-v0", size=7).unwrapped.model,
                  gym_gridloc.windy_maze_model().with_kidnapping(0.05)):
        look, ops = Lookahead(model), BeliefOps(model)
        b = model.prior()
        pred = engine.predict(model, b, 0)
        pz = look.reading_masses(pred[None])[0]
        z = int(np.argmax(pz))
        want, _ = engine.step(model, b, 0, z)
        np.testing.assert_allclose(look.update(pred, z), want, atol=1e-14)
        np.testing.assert_array_equal(ops.update(pred, z), look.update(pred, z))
        np.testing.assert_allclose(look.update(pred[None], [z], pz[[z]])[0], want, atol=1e-14)


def _numeric_threshold_defaults(node: ast.AST) -> list[str]:
    if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
        return []
    args = node.args
    pairs = list(zip(args.args[len(args.args) - len(args.defaults):], args.defaults)) + list(zip(args.kwonlyargs, args.kw_defaults))
    return [a.arg for a, d in pairs if a.arg in ("threshold", "localise_threshold") and isinstance(d, ast.Constant)
            and isinstance(d.value, float)]


def test_the_localise_threshold_is_named_once():
    """0.9 is ``referee.LOCALISE_THRESHOLD``: no signature defaults a threshold to a number of its own."""
    assert _found(lambda n: bool(_numeric_threshold_defaults(n)), set()) == []
    assert _numeric_threshold_defaults(ast.parse("def f(*, threshold: float = 0.9): pass").body[0]) == ["threshold"]
    assert referee.LOCALISE_THRESHOLD == 0.9


def _private_imports(tree: ast.AST) -> list[ast.ImportFrom]:
    """``from package.module import _name``: a private name used outside its module."""
    return [n for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module and n.module.split(".")[0] in
            ("gym_gridloc", "gym_gridloc_agents") and any(a.name.startswith("_") for a in n.names)]


def test_no_module_imports_another_modules_private_names():
    """Private names stay in their module: what another module uses is public (the package's
    ``_numba_kernels`` module is private as a whole and imported as a module, not its names)."""
    found = []
    for path in SOURCES:
        imports = _private_imports(ast.parse(path.read_text(encoding="utf-8")))
        if path.relative_to(ROOT).as_posix() == "gym_gridloc/kernels.py":  # the compiled kernels' one importer
            imports = [n for n in imports if [a.name for a in n.names] != ["_numba_kernels"]]
        found += [_where(path, n) for n in imports]
    assert found == []
    assert _private_imports(ast.parse("from gym_gridloc_agents.planners.ops import BeliefOps, _dedupe"))  # the check sees one


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_one_padded_transition_table(env_id):
    """The engine draws moves from the compiled filter's own padded weights (one table per model,
    not two), and the vector bank stores it once."""
    from gym_gridloc import derived, kernels
    from gym_gridloc.bank import _vector_tables

    model = gym.make(env_id).unwrapped.model
    if not kernels.uses_numba(int(np.prod(model.belief_shape))):
        pytest.skip("numba is not installed (or switched off)")
    weights, keys = derived.of(model).moves
    plan = engine.plan(model)
    assert weights is plan.w and keys is plan.keys
    _, arrays = _vector_tables(model)
    assert sum(a.shape == plan.w.shape and np.array_equal(a, plan.w) for a in arrays) == 1
