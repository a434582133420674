"""The world: grids, sensors and the model object shared by the simulator and the filter."""

from gym_gridloc.core.errors import GridLocError, ImpossibleObservationError, MapError
from gym_gridloc.core.grid import DIRECTIONS, GridMap
from gym_gridloc.core.model import GridModel, Term
from gym_gridloc.core.ring import RingSensor
from gym_gridloc.core.depth import DepthSensor
from gym_gridloc.core.sensors import ColourSensor, Sensor, TableSensor, WallSensor

__all__ = [
    "DIRECTIONS", "GridMap", "GridModel", "Term", "Sensor", "ColourSensor", "RingSensor",
    "WallSensor", "TableSensor", "DepthSensor", "GridLocError", "MapError", "ImpossibleObservationError",
]
