"""What a run allows and defaults to, in plain Python: the one source `RunConfig` and the command
line both read. It imports nothing but `typing`, so that `analytic start` can refuse `--pop 0`
before pydantic, NumPy or pymoo load, and `from gainfarm import RunConfig` loads no optimiser."""

from typing import Literal

POP = 30  # population size
POP_MIN = 4  # NSGA-II's tournament needs a few parents
POP_MAX = 1000
SEED = 0
GENERATIONS_MIN = 1
EVALUATIONS_MIN = 1
ALGORITHM = "nsga2"
# The hypervolume is taken in a normalised objective space, the same for every run so that runs
# compare: f_acc linearly, 0 → 0 and REFERENCE_POINT[0] → 1; f_t logarithmically, F_T_FLOOR → 0
# and REFERENCE_POINT[1] → 1 (torque smoothness spans decades: a step from 100 to 10 (N·m)² is
# worth as much as one from 1 to 0.1). The reference point is (1, 1) there: a controller worse
# than 20 cm mean error or 10^4 (N·m)² mean squared torque step adds nothing. (The paper
# normalises by the worst values among the controllers tested; a fixed point keeps the figure
# comparable across runs and monotone within one.)
REFERENCE_POINT = (0.2, 1e4)  # f_acc in m, f_t in (N·m)²
F_T_FLOOR = 1e-2  # (N·m)²: smoother than this counts as perfectly smooth
# What the optimiser is told: the raw objectives, or the normalised ones the hypervolume is taken
# on (f_t on a log scale).
ObjectiveScaling = Literal["raw", "log"]
OBJECTIVE_SCALINGS: tuple[ObjectiveScaling, ...] = ("raw", "log")
OBJECTIVE_SCALING: ObjectiveScaling = "raw"
# Robust tuning by default: every candidate is scored on the nominal plant and this many of the
# designed plants (analytic.tuning.plants.CORNERS; more add random draws), and each objective
# is its worst over them: a bound that holds on each (docs/tuning.md, "Robust by default").
PLANTS = 2
AGGREGATE = "worst"
# What the second objective measures (`--torque-measure`): each joint's squared torque change
# weighed by its torque limit (schemas.objectives.f_t_joint), so that the wrist counts: on the
# paper's raw f_t (Eq. 1) A1, A2 and A4 make 94-99 % of it and A5-A7 at most 1 %, and a tuned
# front drove the wrist's damping to the bottom of the space. The paper's f_t is `raw`.
TORQUE_MEASURES = {"raw": "f_t", "per-joint": "f_t_joint"}
TORQUE_MEASURE = "per-joint"
REPLICATE = True
# The share of every worker's episodes the referee runs again as they return (spot checks):
# None sizes it as the run starts, so that a worker lying on a tenth of its share of the run's
# episodes is caught with probability 0.99 (analytic.evaluators.replication.sized_rate): for a
# run of 48 evaluations on 3 plants and 2 workers, 0.47; for 600 evaluations, 0.05. A float
# fixes it by hand (0: none).
SPOT_CHECKS: float | None = None
BALANCE = True  # a generic run weighs its trajectories alike at the default gains

Keep = Literal["all", "front"]
KEEPS: tuple[Keep, ...] = ("all", "front")
# The workers keep the logs and the front's are fetched: 179 MB against 1.84 GB for one run.
KEEP: Keep = "front"
