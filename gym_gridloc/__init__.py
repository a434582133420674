"""gym_gridloc: active localisation on grid maps, with exact HMM beliefs.

Importing the package registers ``ColourGrid-v0``, ``RingSensor8x8-v0``, ``WindyMaze-v0`` and
``DepthMaze-v0``, each also in the package's namespace (``gym.make("gym_gridloc/WindyMaze-v0")``,
:data:`NAMESPACED_IDS`): the same environment under two names.
"""

from gymnasium.envs.registration import register, registry

from gym_gridloc.core import (
    DIRECTIONS,
    ColourSensor,
    DepthSensor,
    GridLocError,
    GridMap,
    GridModel,
    ImpossibleObservationError,
    MapError,
    RingSensor,
    Sensor,
    Term,
    WallSensor,
)
from gym_gridloc.envs import ColourGridEnv, DepthMazeEnv, GridLocEnv, RingSensorEnv, WindyMazeEnv
from gym_gridloc.filter import BatchFilter, ForwardFilter
from gym_gridloc.models import (
    colour_grid_model,
    depth_maze_model,
    parse_colour_map,
    parse_maze,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.wrappers import HMMBeliefWrapper, PreviousActionWrapper
from gym_gridloc.inference import FixedLagSmoother, fixed_lag_smooth, forward_backward, smooth, viterbi
from gym_gridloc.particles import ParticleFilter
from gym_gridloc.recording import RecordTrajectory, Trajectory
from gym_gridloc.vector import GridLocVectorEnv

__version__ = "0.1.0"

#: The registered environment ids.
ENV_IDS = ("ColourGrid-v0", "RingSensor8x8-v0", "WindyMaze-v0", "DepthMaze-v0")
#: The namespace the ids are registered in as well, as Gymnasium's namespaced ids.
NAMESPACE = "gym_gridloc"
#: The same environments under their namespaced ids (``gym_gridloc/WindyMaze-v0``).
NAMESPACED_IDS = tuple(f"{NAMESPACE}/{env_id}" for env_id in ENV_IDS)


def _register() -> None:
    # The entry point, max_episode_steps, kwargs and the native vector env (gym.make_vec(id,
    # num_envs=N, vectorization_mode="vector_entry_point")) of each id.
    specs = {
        "ColourGrid-v0": ("envs.colour_grid:ColourGridEnv", 100, {}, "vector:ColourGridVectorEnv"),
        "RingSensor8x8-v0": ("envs.ring_sensor:RingSensorEnv", 400, {"size": (8, 8)}, "vector:RingSensorVectorEnv"),
        "WindyMaze-v0": ("envs.windy_maze:WindyMazeEnv", 100, {}, "vector:WindyMazeVectorEnv"),
        "DepthMaze-v0": ("envs.depth_maze:DepthMazeEnv", 100, {}, "vector:DepthMazeVectorEnv"),
    }
    for env_id, (entry_point, steps, kwargs, vector) in specs.items():
        for name in (env_id, f"{NAMESPACE}/{env_id}"):
            if name not in registry:
                register(id=name, entry_point=f"gym_gridloc.{entry_point}", max_episode_steps=steps, kwargs=kwargs,
                         vector_entry_point=f"gym_gridloc.{vector}")


_register()

__all__ = [
    "ENV_IDS", "NAMESPACE", "NAMESPACED_IDS", "DIRECTIONS", "ColourGridEnv", "ColourSensor", "DepthMazeEnv", "DepthSensor", "depth_maze_model", "ForwardFilter", "GridLocEnv",
    "GridLocError", "GridMap", "GridModel", "HMMBeliefWrapper", "ImpossibleObservationError", "PreviousActionWrapper",
    "MapError", "RingSensor", "RingSensorEnv", "Sensor", "Term", "WallSensor", "WindyMazeEnv",
    "colour_grid_model", "parse_colour_map", "parse_maze", "ring_sensor_model", "windy_maze_model",
    "FixedLagSmoother", "ParticleFilter", "RecordTrajectory", "Trajectory", "fixed_lag_smooth",
    "forward_backward", "smooth", "viterbi", "BatchFilter", "GridLocVectorEnv",
]
