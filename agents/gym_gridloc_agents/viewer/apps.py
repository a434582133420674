"""The two commands' apps: :class:`PlayApp` (a live environment driven by keys) and
:class:`ViewApp` (a recorded episode of a policy, stepped forwards and backwards)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from gym_gridloc_agents.viewer.app import App
from gym_gridloc_agents.viewer.style import DIM, INK, Shown

class PlayApp(App):
    """``gridloc play``: the arrow keys command the robot of a live environment."""

    command = "gridloc play"
    #: The arrow keys of the models with named moves (by their action names), and how the help names them.
    _ARROWS = {("left", "right", "forward"): {"left": 0, "right": 1, "up": 2},
               ("N", "E", "S", "W"): {"up": 0, "right": 1, "down": 2, "left": 3}}
    _MOVES = {("left", "right", "forward"): "left/right arrows: turn   up arrow: move forward",
              ("N", "E", "S", "W"): "arrows: move N / E / S / W (up / right / down / left)"}

    def __init__(self, pg, env, env_id: str, *, seed: int = 0, max_steps: int | None = None, **kwargs: Any) -> None:
        super().__init__(pg, env_id, **kwargs)
        self.env = env
        self.seed = seed
        self.max_steps = max_steps
        self.episode = -1
        self.reset()

    @classmethod
    def _keymap(cls, model) -> dict[str, int]:
        return {str(a): a for a in range(min(model.n_actions, 10))} | cls._ARROWS.get(tuple(model.action_names), {})

    def reset(self) -> None:
        self.episode += 1
        self.episode_seed = None if self.seed is None else self.seed + self.episode
        obs, self.info = self.env.reset(seed=self.episode_seed)
        self.observations = [obs["observation"]]  # this episode's sensor observations and actions
        self.actions: list[int] = []
        self.steps = 0
        self.action: int | None = None
        self.terminated = self.truncated = False
        self.keymap = self._keymap(self.env.unwrapped.model)

    @property
    def done(self) -> bool:
        return self.terminated or self.truncated

    def act(self, action: int) -> None:
        if self.done:
            self.message = "the episode is over: r starts a new one"
            return
        obs, _, terminated, truncated, self.info = self.env.step(int(action))
        self.observations.append(obs["observation"])
        self.actions.append(int(action))
        self.steps += 1
        self.action = int(action)
        self.terminated = bool(terminated)
        self.truncated = bool(truncated) or (self.max_steps is not None and self.steps >= self.max_steps)

    def on_key(self, name: str) -> bool:
        if name == "r":
            self.reset()
        elif name in self.keymap:
            self.act(self.keymap[name])
        else:
            return False
        return True

    def buttons(self) -> list[tuple[str, str, bool]]:
        """One button per action (it presses the action's arrow key, or its digit), new episode,
        the percent numbers."""
        model = self.env.unwrapped.model
        key_of = {}
        for name, a in self.keymap.items():
            if a not in key_of or (key_of[a].isdigit() and not name.isdigit()):
                key_of[a] = name
        acts = [(f"{model.action_names[a]}", key_of[a], False) for a in range(model.n_actions) if a in key_of]
        return [*acts, ("new episode", "r", False), *super().buttons()]

    def shown(self) -> Shown:
        u = self.env.unwrapped
        return Shown(u.model, u.posterior, u.state, u.last_reading, self.action, self.info,
                     estimate=tuple(self.info["estimate"]), full=self.env.filter.full_belief)

    def status(self, s: Shown):
        model = s.model
        act = "-" if s.action is None else model.action_names[s.action]
        seed = "" if self.episode_seed is None else f", seed {self.episode_seed}"
        lines: list[tuple[str, Any]] = [
            (f"{self.env_id}: play", None),
            (f"episode {self.episode + 1}{seed}   step {self.steps}   last action: {act}", INK),
        ]
        lines += self.referee_lines(s, self.env.unwrapped.localise_threshold)
        if self.done:
            why = "localised" if self.terminated else "step limit"
            lines.append((f"episode over ({why}): r starts a new one", DIM))
        return lines

    def help_lines(self) -> list[str]:
        model = self.shown().model
        move = self._MOVES.get(tuple(model.action_names), f"digits: actions ({model.action_legend})")
        return [move, "click: inspect a cell   right click: follow the robot",
                "r: new episode   p: probabilities in percent   esc: quit   (or click the buttons)"]


# -- view -------------------------------------------------------------------------------------------
class ViewApp(App):
    """``gridloc view``: a recorded episode of a policy, stepped forwards and backwards."""

    command = "gridloc view"

    def __init__(self, pg, env, env_id: str, policy, policy_name: str, *, seed: int = 0, max_steps: int | None = None,
                 delay_ms: int = 600, smooth: bool = False, viterbi: bool = False, **kwargs: Any) -> None:
        super().__init__(pg, env_id, **kwargs)
        self.env = env
        self.policy = policy
        self.policy_name = policy_name
        self.max_steps = max_steps
        self.delay = delay_ms / 1000.0
        self.show_smooth = smooth
        self.show_viterbi = viterbi
        self.playing = False
        self._last_advance = 0.0
        self.run_episode(seed)

    def run_episode(self, seed: int) -> None:
        from gym_gridloc_agents.evaluation.rollout import rollout

        from gym_gridloc.inference import forward_backward, viterbi

        self.seed = int(seed)
        self.ep = ep = rollout(self.env, self.policy, self.seed, keep=True, max_steps=self.max_steps)
        self.model = ep.model
        fb = forward_backward(self.model, ep.actions, ep.observations)
        self.filtered, self.smoothed = fb.filtered_positions, fb.smoothed_positions
        self.full_filtered, self.full_smoothed = fb.filtered, fb.smoothed
        self.viterbi_path = [tuple(int(v) for v in p) for p in viterbi(self.model, ep.actions, ep.observations)[0]]
        self.readings = [self.model.sensor.to_reading(o) for o in ep.observations]
        self.k = 0
        self.playing = False

    @property
    def last(self) -> int:
        return self.ep.steps

    def on_key(self, name: str) -> bool:
        steps = {"right": min(self.k + 1, self.last), "left": max(self.k - 1, 0), "home": 0, "end": self.last}
        if name in steps:
            self.k = steps[name]
        elif name == "space":
            if not self.playing and self.k >= self.last:
                self.k = 0
            self.playing = not self.playing
            self._last_advance = time.monotonic()
        elif name == "s":
            self.show_smooth = not self.show_smooth
        elif name == "v":
            self.show_viterbi = not self.show_viterbi
        elif name == "r":
            self.k, self.playing = 0, False
        elif name == "n":
            self.run_episode(self.seed + 1)
        else:
            return False
        return True

    def buttons(self) -> list[tuple[str, str, bool]]:
        """Step, play / pause, first / last, then the toggles and a new episode."""
        return [("|<", "home", False), ("< step", "left", False), ("pause" if self.playing else "play", "space", self.playing),
                ("step >", "right", False), (">|", "end", False), *super().buttons(),
                ("smoothed", "s", self.show_smooth), ("Viterbi", "v", self.show_viterbi), ("new episode", "n", False)]

    def tick(self, now: float) -> None:
        if self.playing and now - self._last_advance >= self.delay:
            self._last_advance = now
            self.k = min(self.k + 1, self.last)
            self.playing = self.k < self.last
            self.dirty = True

    def shown(self) -> Shown:
        k = self.k
        belief = self.smoothed[k] if self.show_smooth else self.filtered[k]
        info = self.ep.infos[k]
        est = (tuple(int(v) for v in np.unravel_index(int(np.argmax(belief)), belief.shape)) if self.show_smooth
               else tuple(info["estimate"]))
        return Shown(self.model, belief, self.ep.states[k], self.readings[k],
                     self.ep.actions[k - 1] if k > 0 else None, info, estimate=est,
                     path=self.viterbi_path[: k + 1] if self.show_viterbi else None,
                     full=(self.full_smoothed if self.show_smooth else self.full_filtered)[k])

    def status(self, s: Shown):
        k = self.k
        ep = self.ep
        act = "-" if s.action is None else s.model.action_names[s.action]
        end = "localised" if ep.terminated else "time limit" if ep.truncated else "stopped (--steps)"
        state = "playing" if self.playing else "paused"
        lines: list[tuple[str, Any]] = [
            (f"{self.env_id}: view, policy {self.policy_name}", None),
            (f"seed {self.seed}   step {k} / {self.last} ({end} at {self.last})   [{state}]", INK),
            (f"action into this step: {act}", INK),
        ]
        lines += self.referee_lines(s, self.env.unwrapped.localise_threshold)
        truth = tuple(s.state[1:])
        sm = self.smoothed[k]
        sm_est = tuple(int(v) for v in np.unravel_index(int(np.argmax(sm)), sm.shape))
        err = abs(sm_est[0] - truth[0]) + abs(sm_est[1] - truth[1])
        on = "ON, shown" if self.show_smooth else "off"
        lines.append((f"[s] smoothed ({on}): estimate {sm_est} p={sm.max():.3f} error {err}", INK if self.show_smooth else DIM))
        vp = self.viterbi_path[k]
        verr = abs(vp[0] - truth[0]) + abs(vp[1] - truth[1])
        on = "ON, shown" if self.show_viterbi else "off"
        lines.append((f"[v] Viterbi ({on}): at step {k} {vp}, error {verr}", INK if self.show_viterbi else DIM))
        return lines

    def help_lines(self) -> list[str]:
        return ["right/left arrows: step   space: play/pause   home/end: first/last",
                "s: smoothed belief   v: Viterbi path   n: new episode   r: rewind",
                "p: probabilities in percent   (or click the buttons)",
                "click: inspect a cell   right click: follow the robot   esc: quit"]
