"""``gridloc play`` / ``gridloc view`` (agents/gym_gridloc_agents/viewer/), without a display (SDL's dummy video
driver): scripted key and mouse events drive the apps and the tests read the drawn surface."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import rendering
from gym_gridloc.filter import ForwardFilter

viewer = pytest.importorskip("gym_gridloc_agents.viewer")
from gym_gridloc_agents.viewer.style import fmt_prob  # noqa: E402


@pytest.fixture
def pg(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    monkeypatch.setenv("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    pygame = pytest.importorskip("pygame")
    yield pygame
    pygame.display.quit()


def post_keys(pg, loop, *keys):
    """Post key presses into pygame's queue and let the loop take them."""
    for k in keys:
        pg.event.post(pg.event.Event(pg.KEYDOWN, key=k, mod=0, unicode="", scancode=0))
        pg.event.post(pg.event.Event(pg.KEYUP, key=k, mod=0, unicode="", scancode=0))
    loop.pump()


def click(pg, loop, app, r, c, button=1):
    x, y, t, _ = app.cell_rect(r, c)
    pg.event.post(pg.event.Event(pg.MOUSEBUTTONDOWN, pos=(x + t // 2, y + t // 2), button=button))
    loop.pump()


def pixel(surface, x, y):
    return tuple(surface.get_at((int(x), int(y)))[:3])


def centre(app, r, c):
    x, y, t, _ = app.cell_rect(r, c)
    return x + t // 2, y + t // 2


def shade_pixel(app, r, c):
    """A pixel of cell (r, c) that no overlay covers: the middle of its top edge, 3 pixels in."""
    x, y, t, _ = app.cell_rect(r, c)
    return x + t // 2, y + 3


def assert_belief_drawn(app, surface, belief):
    """Every free cell is its own colour with opacity = its probability (absolute) over white."""
    model = app.shown().model
    own = rendering.cell_colours(model)
    for r, c in zip(*np.nonzero(model.grid.free)):
        want = (1 - belief[r, c]) * 255 + belief[r, c] * own[r, c]
        assert np.allclose(pixel(surface, *shade_pixel(app, r, c)), want, atol=1.01), (r, c)


def test_play_arrow_keys_step_the_robot_and_the_screen_shows_truth_and_filter(pg):
    app, _ = viewer.play_app(["WindyMaze-v0", "--seed", "3"])
    loop = viewer.Loop(app, window=True)  # the dummy driver's "window"
    loop.show()
    post_keys(pg, loop, pg.K_UP, pg.K_RIGHT, pg.K_DOWN, pg.K_LEFT, pg.K_UP)
    assert app.actions == [0, 1, 2, 3, 0][: app.steps] and app.steps >= 1
    model = app.shown().model
    # The belief shown is the exact filter of the observations and actions taken.
    f = ForwardFilter(model)
    f.reset(app.observations[0])
    for a, o in zip(app.actions, app.observations[1:]):
        f.step(a, o)
    shown = app.shown()
    np.testing.assert_allclose(shown.belief, f.position_belief, atol=1e-12)
    surface = pg.display.get_surface()
    assert pixel(surface, *centre(app, *shown.state[1:])) == rendering.TRUTH_RGB
    assert_belief_drawn(app, surface, f.position_belief)
    # a more probable cell is drawn darker than a less probable one
    free = list(zip(*np.nonzero(model.grid.free)))
    hi = max(free, key=lambda rc: f.position_belief[rc])
    lo = min(free, key=lambda rc: f.position_belief[rc])
    assert f.position_belief[hi] > f.position_belief[lo]
    assert sum(pixel(surface, *shade_pixel(app, *hi))) < sum(pixel(surface, *shade_pixel(app, *lo)))
    info = app.info
    assert any(f"entropy {info['entropy']:.2f} bits" in t for t in app.texts)
    assert any(f"error {info['error']} (Manhattan)" in t for t in app.texts)
    assert any(t.startswith("referee: ") for t in app.texts)


def test_play_r_resets_and_esc_quits(pg):
    app, _ = viewer.play_app(["ColourGrid-v0", "--seed", "5"])
    loop = viewer.Loop(app, window=True)
    loop.show()
    post_keys(pg, loop, pg.K_RIGHT, pg.K_RIGHT)
    assert app.steps >= 1
    post_keys(pg, loop, pg.K_r)
    assert app.steps == 0 and app.episode == 1 and app.actions == []
    fresh = gym_gridloc.ColourGridEnv()
    fresh.reset(seed=6)  # the second episode's seed
    assert app.shown().state == fresh.state
    np.testing.assert_allclose(app.shown().belief, fresh.posterior)
    assert pixel(pg.display.get_surface(), *centre(app, *fresh.state[1:])) == rendering.TRUTH_RGB
    assert app.running
    post_keys(pg, loop, pg.K_ESCAPE)
    assert not app.running


def test_play_depth_maze_turns_and_moves_and_draws_a_heading_arrow(pg):
    app, _ = viewer.play_app(["DepthMaze-v0", "--seed", "1"])
    for name in ("left", "right", "up", "down"):
        app.key(name)
    assert app.actions == [0, 1, 2][: app.steps]
    surf = app.draw()
    layer, r, c = app.shown().state
    x, y, t, _ = app.cell_rect(r, c)
    assert pixel(surf, x + t // 2, y + t // 2) == rendering.TRUTH_RGB
    # the arrow's tip: orange a little way along the heading, not as far the other way
    dr, dc = gym_gridloc.DIRECTIONS[layer]
    ahead = (x + t // 2 + dc * 0.36 * t, y + t // 2 + dr * 0.36 * t)
    behind = (x + t // 2 - dc * 0.36 * t, y + t // 2 - dr * 0.36 * t)
    assert pixel(surf, *ahead) == rendering.TRUTH_RGB and pixel(surf, *behind) != rendering.TRUTH_RGB


@pytest.mark.parametrize("env_id", ["ColourGrid-v0", "WindyMaze-v0", "RingSensor8x8-v0", "DepthMaze-v0"])
def test_inspector_shows_the_models_numbers_for_a_clicked_cell(pg, env_id):
    app, _ = viewer.play_app([env_id, "--seed", "2"])
    loop = viewer.Loop(app, window=True)
    loop.show()
    model = app.shown().model
    free = list(zip(*np.nonzero(model.grid.free)))
    r, c = (int(v) for v in free[len(free) // 2])
    click(pg, loop, app, r, c)
    assert app.pinned == (r, c)
    layer = app.inspected()[0]
    full = app.shown().full
    if model.n_layers > 1 and full[:, r, c].max() > 0:  # the most probable heading there
        assert layer == int(np.argmax(full[:, r, c]))
    data = app.inspector()
    assert data["state"] == (layer, r, c)
    texts = set(app.texts)
    for a in range(model.n_actions):
        want: dict = {}
        for s2, p in model.outcomes((layer, r, c), a):
            key = tuple(int(v) for v in s2)
            want[key] = want.get(key, 0.0) + p
        assert data["transitions"][a] == pytest.approx(want)
        for p in want.values():
            assert fmt_prob(p) in texts
    zs, ps = model.sensor.distribution(r, c, layer)
    assert data["readings"] == pytest.approx({int(z): float(p) for z, p in zip(zs, ps)})
    assert sum(data["readings"].values()) == pytest.approx(1.0)
    shown = " ".join(app.texts)
    for p in data["readings"].values():
        if p > 0:
            assert fmt_prob(p) in shown
    # the clicked cell is framed, a right click goes back to following the robot
    click(pg, loop, app, r, c, button=3)
    assert app.pinned is None and app.inspected() == app.shown().state
    if model.n_layers == 4:  # h cycles the inspected heading
        app.key("h")
        assert app.inspected()[0] == (app.shown().state[0] + 1) % 4


def test_view_steps_back_and_forth_with_smoothing_and_viterbi_toggles(pg):
    app, _ = viewer.view_app(["WindyMaze-v0", "--policy", "random", "--seed", "4", "--steps", "6"])
    loop = viewer.Loop(app, window=True)
    loop.show()
    ep = app.ep
    assert ep.steps == app.last >= 1
    model = app.model
    post_keys(pg, loop, pg.K_RIGHT, pg.K_RIGHT, pg.K_LEFT)
    assert app.k == 1
    filtered = gym_gridloc.forward_backward(model, ep.actions, ep.observations).filtered_positions
    np.testing.assert_allclose(app.shown().belief, filtered[1], atol=1e-12)
    surface = pg.display.get_surface()
    assert pixel(surface, *centre(app, *ep.states[1][1:])) == rendering.TRUTH_RGB
    assert_belief_drawn(app, surface, filtered[1])
    post_keys(pg, loop, pg.K_s)
    smoothed = gym_gridloc.smooth(model, ep.actions, ep.observations)
    np.testing.assert_allclose(app.shown().belief, smoothed[1], atol=1e-12)
    assert_belief_drawn(app, pg.display.get_surface(), smoothed[1])

    def magenta():
        arr = viewer.surface_array(pg, pg.display.get_surface())
        return int(np.all(arr == rendering.PATH_RGB, axis=-1).sum())

    assert magenta() == 0
    post_keys(pg, loop, pg.K_v, pg.K_END)
    path, _ = gym_gridloc.viterbi(model, ep.actions, ep.observations)
    assert app.k == app.last and app.shown().path == [tuple(p) for p in path]
    assert magenta() > 0
    post_keys(pg, loop, pg.K_v, pg.K_s, pg.K_HOME)
    assert app.k == 0 and magenta() == 0
    # space plays: one step per delay
    post_keys(pg, loop, pg.K_SPACE)
    assert app.playing
    app.tick(app._last_advance + app.delay + 0.01)
    assert app.k == 1
    post_keys(pg, loop, pg.K_ESCAPE)
    assert not app.running


def test_view_no_window_records_a_gif_of_every_step(tmp_path, pg, capsys):
    from PIL import Image

    out = tmp_path / "view.gif"
    assert viewer.view_main(["ColourGrid-v0", "--policy", "greedy", "--seed", "1", "--steps", "3",
                             "--no-window", "--record", str(out), "--viterbi"]) == 0
    assert "wrote" in capsys.readouterr().out
    with Image.open(out) as im:
        assert im.format == "GIF" and im.n_frames >= 2
        im.seek(im.n_frames - 1)
        assert im.convert("RGB").size[0] > 400


def test_play_scripted_keys_stop_at_escape(tmp_path, pg):
    from PIL import Image

    out = tmp_path / "play.gif"
    assert viewer.play_main(["WindyMaze-v0", "--keys", "up,escape,up,up", "--no-window", "--record", str(out),
                             "--kw", "drift=0.0"]) == 0
    with Image.open(out) as im:
        assert im.n_frames == 2  # the start and one step; nothing after esc


def test_parse_kw_values():
    assert viewer.parse_kw(["slip=0.2", "size=16,16", "new_map_each_reset=true", "dynamics=passive", "n=3"]) == {
        "slip": 0.2, "size": (16, 16), "new_map_each_reset": True, "dynamics": "passive", "n": 3}
    with pytest.raises(viewer.UsageError):
        viewer.parse_kw(["slip"])


@pytest.mark.parametrize("argv, says", [
    (["Nope-v0"], "not a registered environment"),
    (["ColourGrid-v0", "--kw", "nonsense"], "KEY=VALUE"),
    (["ColourGrid-v0", "--kw", "bogus=1"], "does not build"),
    (["ColourGrid-v0", "--record", "x.avi"], ".gif or .mp4"),
    (["ColourGrid-v0", "--steps", "0"], "--steps"),
    (["ColourGrid-v0", "--layout", "/no/such/map.txt"], "not a file"),
    (["ColourGrid-v0", "--inspect", "9,9"], "outside"),
    (["ColourGrid-v0", "--policy", "dance"], "invalid choice"),
])
def test_bad_arguments_exit_2_with_one_line(pg, capsys, argv, says):
    assert viewer.view_main(argv + ["--no-window"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gridloc view: error:") and says in err and "\n" not in err


def test_mp4_without_imageio_names_what_to_install(pg, monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "imageio", None)
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name.startswith("imageio") else real(name, *a))
    assert viewer.play_main(["ColourGrid-v0", "--no-window", "--steps", "1", "--record", str(tmp_path / "a.mp4")]) == 2
    assert "imageio-ffmpeg" in capsys.readouterr().err


def test_missing_pygame_names_the_render_extra(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pygame", None)
    assert viewer.play_main(["ColourGrid-v0", "--no-window", "--steps", "1"]) == 2
    err = capsys.readouterr().err
    assert "pip install 'gym_gridloc[render]'" in err and err.count("\n") == 1


@pytest.mark.parametrize("command", ["play", "view"])
def test_without_a_display_the_window_commands_fail_at_once_with_one_line(command, tmp_path):
    """No DISPLAY, WAYLAND_DISPLAY or SDL_VIDEODRIVER (a server, ssh, CI): SDL would fall back to
    drawing off screen and the command would wait for keys nobody can press; instead one line
    and exit status 2, at once."""
    import os
    import subprocess

    pytest.importorskip("pygame")
    root = Path(__file__).resolve().parents[2]
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")}
    env["PYTHONPATH"] = os.pathsep.join([str(root), str(root / "agents"), env.get("PYTHONPATH", "")])
    if sys.platform.startswith(("win", "darwin")):
        pytest.skip("a window there needs no DISPLAY")
    done = subprocess.run([sys.executable, "-m", "gym_gridloc_agents.cli", command, "WindyMaze-v0"], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done
    assert done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"gridloc {command}: error: cannot open a window: no display"), lines
    assert "--no-window" in lines[0]


def test_no_display_says_why_only_where_a_window_needs_one():
    from gym_gridloc_agents.viewer.loop import no_display

    assert "DISPLAY" in no_display({}, "linux")
    assert no_display({"DISPLAY": ":0"}, "linux") is None
    assert no_display({"WAYLAND_DISPLAY": "wayland-0"}, "linux") is None
    assert no_display({"SDL_VIDEODRIVER": "dummy"}, "linux") is None  # asked for: the tests' driver
    assert no_display({}, "darwin") is None and no_display({}, "win32") is None


# -- the shading, the numbers, the likelihood view, the buttons ----------------------------------------
def _shown_with(app, belief):
    """The app showing ``belief`` (the rest as it is)."""
    import dataclasses

    s = dataclasses.replace(app.shown(), belief=belief, estimate=None, path=None)
    app.shown = lambda: s
    return s


def test_a_sure_cell_is_its_own_map_colour_and_half_a_belief_half_of_it(pg):
    """ColourGrid: a sure red cell, a sure blue cell and an unsure cell look different; the opacity
    is the probability itself, not relative to the peak."""
    app, _ = viewer.play_app(["ColourGrid-v0", "--seed", "0"])
    model = app.shown().model
    grid = model.grid
    free = list(zip(*np.nonzero(grid.free)))
    colour = {rc: grid.symbols[grid.labels[rc]] for rc in free}
    red = next(rc for rc in free if colour[rc] == "R" and rc != app.shown().state[1:])
    blue = next(rc for rc in free if colour[rc] == "B" and rc != app.shown().state[1:])
    seen = {}
    for name, cell in (("red", red), ("blue", blue)):
        belief = np.zeros(model.shape)
        belief[cell] = 1.0
        _shown_with(app, belief)
        surf = app.draw()
        seen[name] = pixel(surf, *shade_pixel(app, *cell))
        assert seen[name] == rendering.COLOUR_RGB[colour[cell]]
        other = next(rc for rc in free if rc not in (cell, app.shown().state[1:]))
        assert pixel(surf, *shade_pixel(app, *other)) == (255, 255, 255)  # probability 0: white
    belief = np.zeros(model.shape)
    belief[red] = belief[blue] = 0.5
    _shown_with(app, belief)
    surf = app.draw()
    for cell in (red, blue):
        want = 0.5 * 255 + 0.5 * np.array(rendering.COLOUR_RGB[colour[cell]])
        got = pixel(surf, *shade_pixel(app, *cell))
        assert np.allclose(got, want, atol=1.01) and got != seen["red"] and got != seen["blue"]
    assert any("opacity = its probability" in t for t in app.texts) and any("absolute" in t for t in app.texts)


def test_p_and_its_button_show_each_cells_probability_in_percent(pg):
    from gym_gridloc_agents.viewer.style import percent

    app, _ = viewer.play_app(["WindyMaze-v0", "--seed", "3"])
    loop = viewer.Loop(app, window=True)
    loop.show()
    belief = app.shown().belief
    cells = [rc for rc in zip(*np.nonzero(app.shown().model.grid.free)) if belief[rc] > 0]
    assert not app.show_numbers and "% numbers" in app.texts
    post_keys(pg, loop, pg.K_p)
    assert app.show_numbers
    drawn = app.texts.copy()
    assert len(cells) >= 2 and all(percent(belief[rc]) in drawn for rc in cells)
    post_keys(pg, loop, pg.K_p)
    assert not app.show_numbers and not any(percent(belief[rc]) in app.texts for rc in cells if belief[rc] < 0.9)
    post_keys(pg, loop, pg.K_p)
    assert percent(1.0) == "100" and percent(0.5) == "50" and percent(0.032) == "3.2" and percent(1e-4) == "<0.1"
    (x, y, w, h), _ = next(b for b in app.button_rects if b[1] == "p")
    pg.event.post(pg.event.Event(pg.MOUSEBUTTONDOWN, pos=(x + w // 2, y + h // 2), button=1))
    loop.pump()
    assert not app.show_numbers


@pytest.mark.parametrize("env_id", ["ColourGrid-v0", "WindyMaze-v0", "RingSensor8x8-v0", "DepthMaze-v0"])
def test_likelihood_view_draws_the_current_readings_likelihood_over_all_cells(pg, env_id):
    app, _ = viewer.play_app([env_id, "--seed", "2"])
    app.key("up")
    surf = app.draw()
    s = app.shown()
    lik = np.asarray(s.model.sensor.likelihood(int(s.reading)))
    if lik.ndim == 3:  # depth: the robot's heading
        lik = lik[s.state[0]]
    np.testing.assert_allclose(app.likelihood_view(), lik)
    assert any(t.startswith("P(this reading | cell)") for t in app.texts)
    x0, y0, px = app.likelihood_at
    tr, tc = s.state[1:]
    for r, c in zip(*np.nonzero(s.model.grid.free)):
        if abs(r - tr) <= 1 and abs(c - tc) <= 1:
            continue  # the robot's frame
        want = rendering.absolute_shade(rendering.BELIEF_RGB, lik[r, c])
        assert np.allclose(pixel(surf, x0 + c * px + px // 2, y0 + r * px + px // 2), want, atol=1.01), (r, c)


def test_view_buttons_step_play_and_pause(pg):
    app, _ = viewer.view_app(["WindyMaze-v0", "--policy", "random", "--seed", "4", "--steps", "6"])
    loop = viewer.Loop(app, window=True)
    loop.show()

    def press(label):
        (x, y, w, h), _ = next(b for b, (text, _, _) in zip(app.button_rects, app.buttons()) if text == label)
        pg.event.post(pg.event.Event(pg.MOUSEBUTTONDOWN, pos=(x + w // 2, y + h // 2), button=1))
        loop.pump()

    assert app.k == 0
    press("step >")
    press("step >")
    assert app.k == 2
    press("< step")
    assert app.k == 1
    press("play")
    assert app.playing and "pause" in app.texts
    app.tick(app._last_advance + app.delay + 0.01)
    assert app.k == 2
    press("pause")
    assert not app.playing
    press(">|")
    assert app.k == app.last
    press("|<")
    assert app.k == 0
    press("smoothed")
    assert app.show_smooth


def test_play_buttons_take_the_actions(pg):
    app, _ = viewer.play_app(["DepthMaze-v0", "--seed", "1"])
    loop = viewer.Loop(app, window=True)
    loop.show()
    labels = [b[0] for b in app.buttons()]
    assert labels[:3] == ["left", "right", "forward"] and "new episode" in labels
    for label in ("forward", "left"):
        (x, y, w, h), _ = app.button_rects[labels.index(label)]
        pg.event.post(pg.event.Event(pg.MOUSEBUTTONDOWN, pos=(x + w // 2, y + h // 2), button=1))
        loop.pump()
    assert app.actions == [2, 0][: app.steps] and app.steps >= 1
