"""``gridloc play ENV`` and ``gridloc view ENV``: a pygame window to drive the robot and to watch a
policy localise it, with the belief, the estimate and the model's own numbers on screen.

* ``play``: the arrow keys command the robot (``DepthMaze-v0``: left/right turn, up moves forward;
  the others: up/right/down/left = N/E/S/W; digit keys give any action by number).  Every step
  shows the reading, the exact belief (the referee's posterior), the estimate and its error,
  the entropy and whether the referee has declared the robot localised.  ``r`` starts a new
  episode, ``esc`` (or ``q``) quits.
* ``view``: runs one episode of a policy (:func:`gym_gridloc_agents.policies.make_policy`) and
  lets you step through the recorded trajectory (right/left arrows, ``home``/``end``, ``space``
  plays and pauses), overlay the smoothed belief (``s``, :func:`gym_gridloc.smooth`) and the
  Viterbi path (``v``, :func:`gym_gridloc.viterbi`); ``n`` runs a new episode (the next seed),
  ``r`` rewinds.

Both draw each cell in its own map colour (navy on maps without colours) with opacity equal to its
probability (absolute, as seed 000's viewer did; ``p`` writes the probabilities in percent), show
the current reading's likelihood over every cell (seed 003's observation-model view) and have
clickable buttons for what the keys do.  Both have the inspector of the seed documents' transition
and sensor views: click a cell and the
side panel shows ``P(next position | cell, action)`` for every action (``model.outcomes``) and
``P(reading | cell)`` for every reading (``model.sensor.distribution``); until a cell is clicked
(and after a right click or ``c``) it follows the robot.  ``h`` cycles the inspected heading on models
whose hidden state has one.

``--record FILE.gif`` (or ``.mp4`` with imageio and its ffmpeg plugin) writes what was shown;
``--no-window`` draws off screen for scripts and tests (``--keys right,right,s`` feeds key
presses; without ``--keys``, ``view`` shows every step of the episode and ``play --steps N``
presses N random arrow keys).

The event loop is our own, not :func:`gymnasium.utils.play.play`: that loop resets only when an
episode ends (immediately, so the final "localised" frame is never seen) and has no key for a
reset, ignores mouse events (the inspector needs clicks), shows ``env.render()`` alone (no side
panel), calls ``pygame.quit()`` on exit, and steps a live environment, whereas ``view`` moves
back and forth through a recorded episode.  So both commands draw ``rgb_array`` frames of
:mod:`gym_gridloc.rendering` (``Frame``/``rgb_frame``) and a panel with ``pygame.font`` on an
off-screen surface, and a small loop shows it (or, with ``--no-window``, nothing is shown).

pygame (pygame-ce, the ``render`` extra) is imported only when a command runs.

The modules: :mod:`~gym_gridloc_agents.viewer.args` (arguments, building the environment,
importing pygame), :mod:`~gym_gridloc_agents.viewer.style` (colours, fonts, what one picture
shows), :mod:`~gym_gridloc_agents.viewer.app` (the picture, the side panel and the events both
commands share), :mod:`~gym_gridloc_agents.viewer.inspector` (the transition and sensor views),
:mod:`~gym_gridloc_agents.viewer.apps` (play and view), :mod:`~gym_gridloc_agents.viewer.loop`
(the window, the scripted keys, the recording) and :mod:`~gym_gridloc_agents.viewer.commands`
(``gridloc play`` / ``gridloc view``).
"""

from gym_gridloc_agents.viewer.app import App
from gym_gridloc_agents.viewer.apps import PlayApp, ViewApp
from gym_gridloc_agents.viewer.args import UsageError, build_env, import_pygame, parse_kw, parse_value
from gym_gridloc_agents.viewer.commands import play_app, play_main, view_app, view_main
from gym_gridloc_agents.viewer.loop import Loop, Recorder, surface_array
from gym_gridloc_agents.viewer.style import Shown

__all__ = ["App", "Loop", "PlayApp", "Recorder", "Shown", "UsageError", "ViewApp", "build_env", "import_pygame",
           "parse_kw", "parse_value", "play_app", "play_main", "surface_array", "view_app", "view_main"]
