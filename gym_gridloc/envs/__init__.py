"""One file per environment family, each a thin definition over :class:`GridLocEnv`."""

from gym_gridloc.envs.base import GridLocEnv
from gym_gridloc.envs.colour_grid import ColourGridEnv
from gym_gridloc.envs.depth_maze import DepthMazeEnv
from gym_gridloc.envs.ring_sensor import RingSensorEnv
from gym_gridloc.envs.windy_maze import WindyMazeEnv

__all__ = ["GridLocEnv", "ColourGridEnv", "DepthMazeEnv", "RingSensorEnv", "WindyMazeEnv"]
