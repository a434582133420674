"""The source documents' maps and printed numbers, transcribed once: the default maps of the
environments are built from here, and the seed reproduction (``gridloc reproduce``,
:mod:`gym_gridloc.reproduce`) and the tests compare against here.

Sources (``seeds/`` beside the project's SPEC):

* ``000_e6e2653fba623c7b.txt`` -- a colour-grid robot localisation write-up; section "6 Sample
  Output" prints Move 1..Move 11, each with the colour read and the 5x5 belief (printed like
  ``.2136``); section 5.1 prints the 5x5 grid (``.`` marks an obstacle).
* ``004_f2379c22f67c4a5b.txt`` -- an HMM "windy maze" (6 rows x 7 columns); tables in percent with
  ``####`` for obstacles.  Sensor readings are in order (W, N, E, S); ``1`` marks a direction where
  the seed prints ``o``/``O`` (obstacle sensed), ``0`` where it prints ``-``.
* ``001_54f2dc31f27cb9cf.txt`` and ``003_dee3e6ed964e5487.txt`` -- the 8x8 ring-sensor robot: its
  probabilities of "nothing" and its tracking figures.

Values are transcribed exactly as printed (no re-rounding); ``None`` stands for ``####``.
"""

#: Seed 000's 5x5 colour grid (section 5.1; 19 free cells), the default map of ``ColourGrid-v0``.
COLOUR_GRID_LAYOUT = ("R,G,B,Y,B", ".,R,R,G,G", ".,.,B,.,Y", "Y,Y,B,.,R", "B,G,G,.,Y")

# Seed 000, section "6 Sample Output": (colour_read, 5x5 belief table), Move 1..Move 11.
SEED000_MOVES = [
    # Move 1
    ("R", [
        [0.2136, 0.0097, 0.0097, 0.0097, 0.0097],
        [0.0000, 0.2136, 0.2136, 0.0097, 0.0097],
        [0.0000, 0.0000, 0.0097, 0.0000, 0.0097],
        [0.0097, 0.0097, 0.0097, 0.0000, 0.2136],
        [0.0097, 0.0097, 0.0097, 0.0000, 0.0097],
    ]),
    # Move 2
    ("R", [
        [0.3125, 0.0098, 0.0053, 0.0008, 0.0008],
        [0.0000, 0.3125, 0.1166, 0.0053, 0.0008],
        [0.0000, 0.0000, 0.0053, 0.0000, 0.0053],
        [0.0008, 0.0008, 0.0008, 0.0000, 0.2145],
        [0.0008, 0.0008, 0.0008, 0.0000, 0.0053],
    ]),
    # Move 3
    ("R", [
        [0.3735, 0.0115, 0.0024, 0.0002, 0.0001],
        [0.0000, 0.2962, 0.1295, 0.0022, 0.0002],
        [0.0000, 0.0000, 0.0023, 0.0000, 0.0041],
        [0.0001, 0.0001, 0.0001, 0.0000, 0.1734],
        [0.0001, 0.0001, 0.0001, 0.0000, 0.0041],
    ]),
    # Move 4
    ("Y", [
        [0.0957, 0.0578, 0.0121, 0.0091, 0.0000],
        [0.0000, 0.0620, 0.0256, 0.0112, 0.0006],
        [0.0000, 0.0000, 0.0113, 0.0000, 0.3379],
        [0.0005, 0.0006, 0.0002, 0.0000, 0.0300],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.3454],
    ]),
    # Move 5
    ("R", [
        [0.2282, 0.0068, 0.0031, 0.0010, 0.0003],
        [0.0000, 0.1373, 0.0640, 0.0014, 0.0105],
        [0.0000, 0.0000, 0.0015, 0.0000, 0.0213],
        [0.0000, 0.0000, 0.0004, 0.0000, 0.4920],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.0321],
    ]),
    # Move 6
    ("R", [
        [0.3009, 0.0074, 0.0015, 0.0001, 0.0002],
        [0.0000, 0.1503, 0.0623, 0.0015, 0.0007],
        [0.0000, 0.0000, 0.0013, 0.0000, 0.0108],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.4513],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.0116],
    ]),
    # Move 7
    ("R", [
        [0.3738, 0.0086, 0.0013, 0.0001, 0.0000],
        [0.0000, 0.1521, 0.0635, 0.0012, 0.0002],
        [0.0000, 0.0000, 0.0012, 0.0000, 0.0088],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.3800],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.0091],
    ]),
    # Move 8
    ("Y", [
        [0.0539, 0.0256, 0.0035, 0.0028, 0.0000],
        [0.0000, 0.0180, 0.0074, 0.0031, 0.0005],
        [0.0000, 0.0000, 0.0031, 0.0000, 0.4176],
        [0.0000, 0.0000, 0.0001, 0.0000, 0.0371],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.4273],
    ]),
    # Move 9
    ("Y", [
        [0.0002, 0.0001, 0.0001, 0.0020, 0.0002],
        [0.0000, 0.0001, 0.0000, 0.0002, 0.0068],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.3027],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.0173],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.6700],
    ]),
    # Move 10
    ("G", [
        [0.0001, 0.0012, 0.0002, 0.0002, 0.0009],
        [0.0000, 0.0000, 0.0000, 0.0186, 0.6365],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.0588],
        [0.0000, 0.0000, 0.0000, 0.0000, 0.0940],
        [0.0000, 0.0001, 0.0000, 0.0000, 0.1893],
    ]),
    # Move 11
    ("B", [
        [0.0001, 0.0001, 0.0022, 0.0011, 0.8050],
        [0.0000, 0.0001, 0.0011, 0.0376, 0.0410],
        [0.0000, 0.0000, 0.0001, 0.0000, 0.0486],
        [0.0000, 0.0000, 0.0001, 0.0000, 0.0250],
        [0.0001, 0.0000, 0.0000, 0.0000, 0.0379],
    ]),
]

#: Seed 004's 6x7 windy maze (31 free cells), the default map of ``WindyMaze-v0``.
WINDY_MAZE_LAYOUT = ("OOOOOOO", "OO####O", "OO#OO#O", "O##OO#O", "OOOO##O", "OOOOOOO")

# Seed 004, "Initial location probabilities" (percent; None = ####).
SEED004_INITIAL = [
    [3.23, 3.23, 3.23, 3.23, 3.23, 3.23, 3.23],
    [3.23, 3.23, None, None, None, None, 3.23],
    [3.23, 3.23, None, 3.23, 3.23, None, 3.23],
    [3.23, None, None, 3.23, 3.23, None, 3.23],
    [3.23, 3.23, 3.23, 3.23, None, None, 3.23],
    [3.23, 3.23, 3.23, 3.23, 3.23, 3.23, 3.23],
]

# Seed 004: (kind, arg, 6x7 table in percent), in printed order.
#   kind "filter": arg = sensed obstacles (W, N, E, S), 1 where the seed prints o
#   kind "predict": arg = action direction
SEED004_TABLES = [
    # Filtering after evidence [-, -, -, o]
    ("filter", (0, 0, 0, 1), [
        [0.07, 0.4, 3.42, 3.42, 3.42, 3.42, 0.07],
        [0.4, 0.4, None, None, None, None, 0.07],
        [0.4, 3.42, None, 0.07, 0.07, None, 0.07],
        [0.07, None, None, 0.4, 3.42, None, 0.07],
        [0.4, 0.4, 0.4, 0.4, None, None, 0.07],
        [3.42, 20.52, 20.52, 20.52, 3.42, 3.42, 3.42],
    ]),
    # Prediction after Action N
    ("predict", "N", [
        [0.42, 0.99, 3.12, 3.42, 3.42, 3.09, 0.46],
        [0.4, 2.82, None, None, None, None, 0.07],
        [0.44, 0.38, None, 0.39, 2.8, None, 0.07],
        [0.34, None, None, 0.7, 0.38, None, 0.07],
        [2.82, 16.82, 16.82, 16.5, None, None, 2.75],
        [2.39, 2.39, 4.1, 2.39, 5.13, 3.42, 0.68],
    ]),
    # Filtering after evidence [-, o, -, -]
    ("filter", (0, 1, 0, 0), [
        [0.18, 2.51, 1.31, 1.44, 1.44, 1.3, 0.19],
        [0.02, 0.14, None, None, None, None, 0],
        [0.02, 0, None, 0.16, 1.18, None, 0],
        [0, None, None, 0.03, 0, None, 0],
        [0.14, 42.5, 42.5, 0.82, None, None, 0.02],
        [0.02, 0.12, 0.2, 0.12, 2.16, 1.44, 0.01],
    ]),
    # Prediction after Action E
    ("predict", "E", [
        [0.02, 0.41, 2.27, 1.34, 1.44, 1.41, 1.21],
        [0.02, 0.38, None, None, None, None, 0.02],
        [0, 0.03, None, 0.02, 1.19, None, 0],
        [0.02, None, None, 0.1, 0.15, None, 0],
        [0, 4.37, 38.27, 34.67, None, None, 0.02],
        [0.02, 4.28, 4.37, 0.26, 0.53, 2.02, 1.16],
    ]),
    # Filtering after evidence [-, o, -, -]
    ("filter", (0, 1, 0, 0), [
        [0.01, 0.89, 0.83, 0.49, 0.52, 0.51, 0.44],
        [0, 0.02, None, None, None, None, 0],
        [0, 0, None, 0.01, 0.43, None, 0],
        [0, None, None, 0, 0, None, 0],
        [0, 9.54, 83.51, 1.48, None, None, 0],
        [0, 0.18, 0.19, 0.01, 0.19, 0.73, 0.01],
    ]),
    # Prediction after Action E
    ("predict", "E", [
        [0, 0.1, 0.88, 0.76, 0.49, 0.52, 0.81],
        [0, 0.1, None, None, None, None, 0.04],
        [0, 0, None, 0, 0.4, None, 0],
        [0, None, None, 0.15, 0.05, None, 0],
        [0, 0.97, 16, 68, None, None, 0],
        [0, 0.97, 8.52, 0.3, 0.05, 0.3, 0.59],
    ]),
    # Filtering after evidence [-, -, o, -]
    ("filter", (0, 0, 1, 0), [
        [0, 0, 0, 0, 0, 0, 0.2],
        [0, 0.15, None, None, None, None, 0.01],
        [0, 0, None, 0, 0.1, None, 0],
        [0, None, None, 0, 0.01, None, 0],
        [0, 0.03, 0.46, 98.61, None, None, 0],
        [0, 0.03, 0.24, 0.01, 0, 0, 0.14],
    ]),
]


#: Seed 000's readings: moves 1-8, the unprinted move (index 8) that read Y, moves 9-11.
SEED000_READINGS = tuple("RRRYRRRY") + ("Y",) + tuple("YGB")
#: Index of the unprinted move in :data:`SEED000_READINGS`.
SEED000_SKIPPED = 8

#: Seed 001's P(nothing) on 8x8, keyed by the sorted pair of (distance to the nearest edge, capped
#: at 2) of row and column: corner, edge next to a corner, other edge, (1,1)-type, rest of the inner
#: ring, inside.
SEED001_NOTHING = {(0, 0): 0.625, (0, 1): 0.5, (0, 2): 0.425, (1, 1): 0.325, (1, 2): 0.225, (2, 2): 0.1}

#: Seed 003's tracking figures (passive dynamics, 5x5, 20 runs of 1000 steps): the fraction of
#: steps whose most probable position is exactly right, and the mean Manhattan error.
SEED003_HIT_RANGE = (0.28, 0.33)
SEED003_ERROR_RANGE = (1.2, 2.0)
