"""The evolution step: NSGA-II (pymoo) through ask and tell, and the hypervolume of its front.

Pure: no farm, no files. The caller evaluates each asked generation however it likes (the farm,
in any order) and tells the objectives back in the order asked, so the outcome depends on the seed
and the objectives only, never on which result arrived first.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pymoo.algorithms.moo.nsga2 import NSGA2
from pymoo.core.population import Population
from pymoo.core.problem import Problem
from pymoo.indicators.hv import HV
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

from analytic.search_space import SearchSpace
from schemas.gains import PDGains

# The hypervolume is taken in a normalised objective space, the same for every run so that runs
# compare: f_acc linearly, 0 → 0 and REFERENCE_POINT[0] → 1; f_t logarithmically, F_T_FLOOR → 0
# and REFERENCE_POINT[1] → 1 (torque smoothness spans decades: a step from 100 to 10 (N·m)² is
# worth as much as one from 1 to 0.1). The reference point is (1, 1) there: a controller worse
# than 20 cm mean error or 10^4 (N·m)² mean squared torque step adds nothing. (The paper
# normalises by the worst values among the controllers tested; a fixed point keeps the figure
# comparable across runs and monotone within one.)
REFERENCE_POINT = (0.2, 1e4)  # f_acc in m, f_t in (N·m)²
F_T_FLOOR = 1e-2  # (N·m)²: smoother than this counts as perfectly smooth


@dataclass(frozen=True)
class Candidate:
    gains: PDGains
    objectives: tuple[float, float]  # f_acc, f_t: means over the trajectory set


class GainProblem(Problem):
    """The decision space for pymoo; evaluation happens outside, through ask and tell."""

    def __init__(self, space: SearchSpace):
        super().__init__(n_var=len(space.lower), n_obj=2, xl=space.lower, xu=space.upper)


class Evolution:
    """NSGA-II over the gains. Picklable: a checkpoint is this object, random state included."""

    def __init__(
        self,
        pop_size: int,
        seed: int,
        space: SearchSpace | None = None,
        steady_state: bool = False,
    ):
        """Generational NSGA-II asks a whole generation at a time. The steady-state variant
        (mu + 1) asks one offspring at a time (ask_one) and takes each result as it comes
        (tell_one), so that no worker waits for a generation's slowest episode."""
        self.space = space or SearchSpace()
        self.pop_size = pop_size
        self.algorithm = NSGA2(
            pop_size=pop_size, n_offsprings=1 if steady_state else None, eliminate_duplicates=True
        )
        self.algorithm.setup(GainProblem(self.space), seed=seed, verbose=False)
        self._asked = None
        self.generation = 0
        self.evaluations = 0
        # Every non-dominated point seen. NSGA-II's own population can drop a front member when
        # crowding trims a large first front; the archive never does, so its hypervolume never
        # falls and the front reported is the best found.
        self._archive_x = np.empty((0, len(self.space.lower)))
        self._archive_f = np.empty((0, 2))
        # Every point told, dominated or not: a corrected point (validation by replication,
        # analytic.replication) can uncover one that a false one had dominated.
        self._seen_x = np.empty((0, len(self.space.lower)))
        self._seen_f = np.empty((0, 2))

    def __setstate__(self, state: dict) -> None:
        """Checkpoints from before `_seen_*` know only the archive: it stands in for them."""
        self.__dict__.update(state)
        if "_seen_x" not in state:
            self._seen_x, self._seen_f = self._archive_x.copy(), self._archive_f.copy()

    def ask(self) -> list[PDGains]:
        """The next generation's candidates (the first is the random initial population)."""
        if self._asked is None:
            self._asked = self.algorithm.ask()
        return [self.space.gains(x) for x in self._asked.get("X")]

    def tell(self, objectives: Sequence[tuple[float, float]]) -> None:
        """The objectives of the candidates last asked, in the order asked."""
        if self._asked is None or len(objectives) != len(self._asked):
            raise ValueError("tell() takes one pair of objectives per candidate asked")
        self._tell(self._asked, objectives)
        self._asked = None
        self.generation += 1

    def ask_one(self) -> tuple[Population, PDGains]:
        """Steady state, after the first generation: one new candidate, and the handle to tell
        its objectives with."""
        if self._asked is not None or self.generation == 0:
            raise RuntimeError("ask_one() follows a first generation asked and told whole")
        offspring = self.algorithm.ask()
        while len(offspring) == 0:  # every offspring was a duplicate: draw again
            offspring = self.algorithm.ask()
        return offspring[:1], self.space.gains(offspring.get("X")[0])

    def tell_one(self, handle: Population, objectives: tuple[float, float]) -> None:
        self._tell(handle, [objectives])
        self.generation = self.evaluations // self.pop_size

    def _tell(self, individuals: Population, objectives: Sequence[tuple[float, float]]) -> None:
        f = np.asarray(objectives, dtype=float)
        individuals.set("F", f)
        self.algorithm.tell(infills=individuals)
        self._seen_x = np.vstack([self._seen_x, individuals.get("X")])
        self._seen_f = np.vstack([self._seen_f, f])
        x = np.vstack([self._archive_x, individuals.get("X")])
        f = np.vstack([self._archive_f, f])
        first = non_dominated_indices(f)
        self._archive_x, self._archive_f = x[first], f[first]
        self.evaluations += len(individuals)

    def correct(self, gains: PDGains, objectives: tuple[float, float]) -> None:
        """A candidate's objectives were false (a replica outvoted its log): take the true ones,
        in the archive, among the points seen and in NSGA-II's population."""
        for row, x in enumerate(self._seen_x):
            if self.space.gains(x) == gains:
                self._seen_f[row] = objectives
        first = non_dominated_indices(self._seen_f)
        self._archive_x, self._archive_f = self._seen_x[first], self._seen_f[first]
        population = self.algorithm.pop
        if population is not None:
            for individual in population:
                if self.space.gains(individual.X) == gains:
                    individual.set("F", np.asarray(objectives, dtype=float))

    def front(self) -> list[Candidate]:
        """The non-dominated candidates among all evaluated so far, by f_acc."""
        members = [
            Candidate(self.space.gains(x), (float(f[0]), float(f[1])))
            for x, f in zip(self._archive_x, self._archive_f, strict=True)
        ]
        return sorted(members, key=lambda member: member.objectives)


def non_dominated_indices(f: np.ndarray) -> np.ndarray:
    """Indices of the rows of `f` no other row dominates, in their original order."""
    if len(f) == 0:
        return np.empty(0, dtype=int)
    first = NonDominatedSorting().do(np.asarray(f, dtype=float), only_non_dominated_front=True)
    return np.sort(first)


def normalise(
    points: Sequence[tuple[float, float]], reference: tuple[float, float] = REFERENCE_POINT
) -> np.ndarray:
    """Objectives in the space the hypervolume is measured in (see REFERENCE_POINT)."""
    f = np.asarray(points, dtype=float).reshape(-1, 2)
    f_acc = f[:, 0] / reference[0]
    f_t = np.log(np.maximum(f[:, 1], F_T_FLOOR) / F_T_FLOOR) / np.log(reference[1] / F_T_FLOOR)
    return np.column_stack([f_acc, f_t])


def hypervolume(
    points: Sequence[tuple[float, float]], reference: tuple[float, float] = REFERENCE_POINT
) -> float:
    """Hypervolume of `points`, normalised, against the reference point: in [0, 1]."""
    if not points:
        return 0.0
    normalised = normalise(points, reference)
    return float(HV(ref_point=np.ones(2))(normalised))
