"""What a run allows and defaults to, in plain Python: the one source `RunConfig` and the command
line both read. It imports nothing but `typing`, so that `analytic start` can refuse `--pop 0`
before pydantic, NumPy or pymoo load."""

from typing import Literal

POP = 30  # population size
POP_MIN = 4  # NSGA-II's tournament needs a few parents
POP_MAX = 1000
SEED = 0
GENERATIONS_MIN = 1
EVALUATIONS_MIN = 1
ALGORITHM = "nsga2"
# What the optimiser is told: the raw objectives, or the normalised ones the hypervolume is taken
# on (f_t on a log scale).
ObjectiveScaling = Literal["raw", "log"]
OBJECTIVE_SCALINGS: tuple[ObjectiveScaling, ...] = ("raw", "log")
OBJECTIVE_SCALING: ObjectiveScaling = "raw"
REPLICATE = True
BALANCE = True  # a generic run weighs its trajectories alike at the default gains

Keep = Literal["all", "front"]
KEEPS: tuple[Keep, ...] = ("all", "front")
# The workers keep the logs and the front's are fetched: 179 MB against 1.84 GB for one run.
KEEP: Keep = "front"
