"""The evolution step: a multi-objective optimiser (pymoo's, or Optuna's TPE) through ask and
tell, and the hypervolume of its front.

Pure: no farm, no files. The caller evaluates each asked generation however it likes (the farm,
in any order) and tells the objectives back in the order asked, so the outcome depends on the seed
and the objectives only, never on which result arrived first.

The optimiser is NSGA-II by default; ALGORITHMS lists the other built-in ones, all generational (a
whole population asked, then told): pymoo's NSGA-III, SMS-EMOA, MOEA/D and AGE-MOEA-II; "tpe",
Optuna's multi-objective TPE through Optuna's ask and tell; and "random", uniform
random sampling of the search space, a population a generation, the baseline any optimiser must
beat. NSGA-II and TPE also run in a steady state (STEADY_STATE: one candidate asked as another
is told). Each is a factory in a module of its own (analytic/tuning/algorithms/), registered in
the gainfarm.algorithms group of gainfarm.plugins by an entry point, as a plug-in adds its own
(`optimiser`: what a factory takes and what it returns).

Whatever the optimiser, the front is this module's archive of every non-dominated point told, in
raw units. The optimiser itself may be told the objectives as the hypervolume sees them
(objective_scaling "log": `normalise`, f_t on a log scale) instead of raw (f_t spans six decades,
and crowding on raw f_t neglects the smooth end).

Constraints (the safety limits, schemas.limits: g ≤ 0 met) are told with the objectives. The
archive, and so the front, holds feasible points only. The optimiser ranks feasibility first:
pymoo's NSGA-II, NSGA-III, SMS-EMOA and AGE-MOEA-II by their own constraint handling (the
problem declares the constraints, so survival keeps the feasible before the least violating,
and tournaments compare violations first); Optuna's TPE by its constraints_func (a trial's
constraint values replayed with it); pymoo's MOEA/D has none (it refuses a constrained problem),
so it, and any plug-in without a pymoo problem, is told an infeasible point's objectives as
worse than any episode's (NO_EPISODE, times 1 + the violation); random sampling needs nothing.
"""

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from pymoo.core.individual import calc_cv
from pymoo.core.population import Population
from pymoo.core.problem import Problem
from pymoo.indicators.hv import HV
from pymoo.operators.sampling.rnd import FloatRandomSampling
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

from gainfarm import plugins
from gainfarm.analytic.tuning.algorithms import STEADY_STATE, steady_state_refusal
from gainfarm.analytic.tuning.defaults import F_T_FLOOR, OBJECTIVE_SCALINGS, REFERENCE_POINT
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.objectives import NO_EPISODE

# The hypervolume's box (REFERENCE_POINT, F_T_FLOOR) is defaults.py's: a RunConfig reads it
# without loading pymoo.

# The built-in optimisers, the default first; plugins.names(plugins.ALGORITHMS) adds the plug-ins.
ALGORITHMS: tuple[str, ...] = plugins.builtin_names(plugins.ALGORITHMS)


@dataclass(frozen=True)
class Candidate:
    gains: PDGains
    objectives: tuple[float, float]  # f_acc, f_t: means over the trajectory set


class Optimiser(Protocol):
    """What the evolution step asks and tells, as pymoo's algorithms have it (any pymoo
    algorithm set up on GainProblem(space) is one). The decision variables are the search
    space's (log10 of each gain, SearchSpace.lower to .upper); the two objectives are minimised.
    It may also hold `pop`, the population it keeps (a pymoo Population, or None): objectives
    that replication finds false are corrected there too (Evolution.correct); and one that is
    not set up on a pymoo problem may say whether it ranks constraints itself,
    `rank_constraints(count) -> bool` (else it is told an infeasible point as the worst)."""

    def ask(self) -> Population:
        """The next candidates (X set), a generation of them."""
        ...

    def tell(self, infills: Population) -> None:
        """The candidates last asked, in the order asked, with their objectives (F) set."""
        ...


def optimiser(
    algorithm: str, pop_size: int, seed: int, space: SearchSpace, steady_state: bool = False
) -> Optimiser:
    """`algorithm` (a name of the gainfarm.algorithms group) set up on the gain problem.

    A plug-in of that group is a factory called as factory(pop_size=, seed=, space=) that
    returns an Optimiser; it is deterministic given the seed. A checkpoint holds what it returns,
    so it is picklable, and the factory declares the globals its pickle names
    (`checkpoint_globals`: analytic.tuning.checkpoint). Steady state is STEADY_STATE's only.
    PluginError (a ValueError) if this installation has no such algorithm.
    """
    if steady_state and algorithm not in STEADY_STATE:
        raise ValueError(steady_state_refusal(algorithm))
    factory = plugins.load(plugins.ALGORITHMS, algorithm)
    made = factory(
        pop_size=pop_size,
        seed=seed,
        space=space,
        **({"steady_state": True} if steady_state else {}),
    )
    if not (callable(getattr(made, "ask", None)) and callable(getattr(made, "tell", None))):
        raise plugins.PluginError(
            f"{plugins.ALGORITHMS}: {algorithm!r} made a {type(made).__name__}, which has no "
            "ask() and tell()"
        )
    return made


class FromTheDefaults(FloatRandomSampling):
    """pymoo's random sampling with the robot's default gains as the first sample (`Evolution`'s
    `from_defaults`): a tuning starts from the factory's controller, which it is judged against
    (analytic.tuning.picks), so the front holds it or what dominates it. The other samples are
    the ones random sampling draws, the same random state."""

    # The gains as plain numbers (Kp then Kd; a checkpoint pickles them): the iiwa 14's for a
    # checkpoint from before other arms, which holds none.
    defaults: tuple[float, ...] = DEFAULT_GAINS.kp + DEFAULT_GAINS.kd

    def __init__(self, defaults: PDGains = DEFAULT_GAINS) -> None:
        super().__init__()
        self.defaults = tuple(defaults.kp + defaults.kd)

    def _do(self, problem: Problem, n_samples: int, *args: Any, **kwargs: Any) -> np.ndarray:
        x = super()._do(problem, n_samples, *args, **kwargs)
        x[0] = np.clip(np.log10(self.defaults), problem.xl, problem.xu)
        return x


class Evolution:
    """An optimiser over the gains (NSGA-II by default). Picklable: a checkpoint is this object,
    random state included."""

    def __init__(
        self,
        pop_size: int,
        seed: int,
        space: SearchSpace | None = None,
        steady_state: bool = False,
        algorithm: str = "nsga2",
        objective_scaling: str = "raw",
        reference: tuple[float, float] = REFERENCE_POINT,
        constraints: int = 0,
        from_defaults: bool = False,
        defaults: PDGains = DEFAULT_GAINS,
    ):
        """Generational algorithms ask a whole generation at a time. NSGA-II's steady-state
        variant (mu + 1) asks one offspring at a time (ask_one) and takes each result as it
        comes (tell_one), so that no worker waits for a generation's slowest episode; TPE's asks
        one trial at a time likewise, each sampled from every result told so far.
        `objective_scaling` "log" tells the optimiser `normalise(objectives, reference)`
        instead of the raw objectives; the archive, the front and everything recorded stay raw.
        `constraints`: how many constraint values each point is told with (none: unconstrained).
        `from_defaults`: a pymoo algorithm's first population holds the default gains
        (FromTheDefaults); the others (TPE, random sampling, a plug-in's) sample as they do.
        `defaults`: the robot's default gains, which `space` is built around (the iiwa 14's,
        its space, by default).
        """
        if objective_scaling not in OBJECTIVE_SCALINGS:
            raise ValueError(
                f"unknown objective scaling {objective_scaling!r}: one of "
                f"{', '.join(OBJECTIVE_SCALINGS)}"
            )
        self.space = space or SearchSpace()
        self.pop_size = pop_size
        self.algorithm_name = algorithm
        self.objective_scaling = objective_scaling
        self.reference = tuple(reference)
        self.algorithm = optimiser(algorithm, pop_size, seed, self.space, steady_state)
        initialization = getattr(self.algorithm, "initialization", None)
        if from_defaults and hasattr(initialization, "sampling"):
            # Read at the first ask, not at set-up: the algorithm is otherwise as it was made.
            initialization.sampling = FromTheDefaults(defaults)
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
        self._front: list[Candidate] | None = None  # front(), until the archive changes
        self.constraints = 0
        self._ranks_feasibility = False  # whether the optimiser handles the constraints itself
        self._seen_g = np.empty((0, 0))
        self.constrain(constraints)

    def constrain(self, count: int) -> None:
        """From now on, tell `count` constraint values with each point (an unconstrained
        evolution, or one from an older checkpoint, whose points told so far count as met)."""
        if count == self.constraints:
            return
        if self.constraints:
            raise ValueError(f"told {self.constraints} constraints so far, not {count}")
        self.constraints = count
        self._seen_g = np.zeros((len(self._seen_f), count))
        self._ranks_feasibility = _declare(self.algorithm, count)

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_front": None}  # derived; and a checkpoint holds no Candidate

    def __setstate__(self, state: dict) -> None:
        """Checkpoints from before `_seen_*` know only the archive: it stands in for them.
        Checkpoints from before the choice of algorithm are NSGA-II's, told raw objectives."""
        defaults = {
            "algorithm_name": "nsga2",
            "objective_scaling": "raw",
            "reference": REFERENCE_POINT,
            "constraints": 0,
            "_ranks_feasibility": False,
        }
        self.__dict__.update({**defaults, **state, "_front": None})
        if "_seen_x" not in state:
            self._seen_x, self._seen_f = self._archive_x.copy(), self._archive_f.copy()
        if "_seen_g" not in state:  # from before constraints: none told
            self._seen_g = np.zeros((len(self._seen_f), 0))

    def ask(self) -> list[PDGains]:
        """The next generation's candidates (the first is the random initial population)."""
        if self._asked is None:
            self._asked = self.algorithm.ask()
        return [self.space.gains(x) for x in self._asked.get("X")]

    def tell(
        self,
        objectives: Sequence[tuple[float, float]],
        constraints: Sequence[Sequence[float]] | None = None,
    ) -> None:
        """The objectives of the candidates last asked, in the order asked, and their
        constraint values (`constraints` of each; none: all met)."""
        if self._asked is None or len(objectives) != len(self._asked):
            raise ValueError("tell() takes one pair of objectives per candidate asked")
        self._tell(self._asked, objectives, constraints)
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

    def tell_one(
        self,
        handle: Population,
        objectives: tuple[float, float],
        constraints: Sequence[float] | None = None,
    ) -> None:
        self._tell(handle, [objectives], None if constraints is None else [constraints])
        self.generation = self.evaluations // self.pop_size

    def _constraint_rows(self, count: int, constraints: object) -> np.ndarray:
        if constraints is None:
            return np.zeros((count, self.constraints))
        g = np.asarray(constraints, dtype=float)
        if g.shape != (count, self.constraints):
            raise ValueError(f"tell() takes {self.constraints} constraint values per candidate")
        return g

    def _tell(
        self,
        individuals: Population,
        objectives: Sequence[tuple[float, float]],
        constraints: Sequence[Sequence[float]] | None = None,
    ) -> None:
        f = np.asarray(objectives, dtype=float).reshape(-1, 2)
        g = self._constraint_rows(len(f), constraints)
        self._set(individuals, f, g)
        self.algorithm.tell(infills=individuals)
        self._seen_x = np.vstack([self._seen_x, individuals.get("X")])
        self._seen_f = np.vstack([self._seen_f, f])
        self._seen_g = np.vstack([self._seen_g, g])
        met = feasible_rows(g)
        x = np.vstack([self._archive_x, individuals.get("X")[met]])
        f = np.vstack([self._archive_f, f[met]])
        first = non_dominated_indices(f)
        self._archive_x, self._archive_f = x[first], f[first]
        self._front = None
        self.evaluations += len(individuals)

    def _set(self, individuals: Population, f: np.ndarray, g: np.ndarray) -> None:
        """Tell the optimiser's individuals their objectives and constraints, as it takes them."""
        told = self.seen_by_optimiser(f)
        if self.constraints and self._ranks_feasibility:
            individuals.set("G", g)
            individuals.set("CV", np.array([calc_cv(G=row) for row in g]).reshape(-1, 1))
        elif self.constraints:  # it ranks by objectives alone: an infeasible point is worst
            violation = np.array([calc_cv(G=row) for row in g])
            worst = self.seen_by_optimiser([NO_EPISODE])[0]
            told = np.where((violation > 0)[:, None], worst * (1 + violation[:, None]), told)
        individuals.set("F", told)

    def correct(
        self,
        gains: PDGains,
        objectives: tuple[float, float],
        constraints: Sequence[float] | None = None,
    ) -> list[int]:
        """A candidate's objectives (and constraint values) were false (a replica outvoted its
        log): take the true ones, in the archive, among the points seen and in the optimiser's
        population. Returns where the candidate was told, as indices into the points told in
        order (empty for a checkpoint from before every point was kept, whose points seen are
        its archive)."""
        g = self._constraint_rows(1, None if constraints is None else [constraints])
        rows = []
        for row, x in enumerate(self._seen_x):
            if self.space.gains(x) == gains:
                self._seen_f[row] = objectives
                self._seen_g[row] = g[0]
                rows.append(row)
        met = np.flatnonzero(feasible_rows(self._seen_g))
        first = met[non_dominated_indices(self._seen_f[met])]
        self._archive_x, self._archive_f = self._seen_x[first], self._seen_f[first]
        self._front = None
        population = getattr(self.algorithm, "pop", None)  # a plug-in may hold none
        if population is not None:
            for individual in population:
                if self.space.gains(individual.X) == gains:
                    self._set(Population([individual]), np.array([objectives]), g)
        return rows if len(self._seen_f) == self.evaluations else []

    @property
    def infeasible(self) -> int:
        """How many of the points told broke a constraint."""
        return int(np.count_nonzero(~feasible_rows(self._seen_g)))

    def seen_by_optimiser(
        self, objectives: Sequence[tuple[float, float]] | np.ndarray
    ) -> np.ndarray:
        """Raw objectives as the optimiser is told them (objective_scaling), one row each."""
        f = np.asarray(objectives, dtype=float).reshape(-1, 2)
        if self.objective_scaling == "log":
            return normalise(f, self.reference)
        return f

    def front(self) -> list[Candidate]:
        """The non-dominated candidates among all evaluated so far, by f_acc."""
        if self._front is None:  # asked several times a generation; made once per change
            members = [
                Candidate(self.space.gains(x), (float(f[0]), float(f[1])))
                for x, f in zip(self._archive_x, self._archive_f, strict=True)
            ]
            self._front = sorted(members, key=lambda member: member.objectives)
        return list(self._front)


def _declare(algorithm: Any, constraints: int) -> bool:
    """Set an optimiser up to rank `constraints` itself, feasibility first; False if it cannot
    (it is then told an infeasible point as the worst: Evolution._set)."""
    if not constraints:
        return False
    rank = getattr(algorithm, "rank_constraints", None)
    if callable(rank):  # one that is not pymoo's says whether it ranks them (Optimiser)
        return bool(rank(constraints))
    problem = getattr(algorithm, "problem", None)
    if isinstance(problem, Problem) and not _is_moead(algorithm):
        # pymoo's survival splits by feasibility when the problem has constraints, and its
        # tournaments compare the violation (CV) first.
        problem.n_ieq_constr = constraints
        return True
    return False


def _is_moead(algorithm: Any) -> bool:
    """Whether `algorithm` is pymoo's MOEA/D (no MOEA/D was made if its module is not loaded)."""
    module = sys.modules.get("pymoo.algorithms.moo.moead")
    return module is not None and isinstance(algorithm, module.MOEAD)


def feasible_rows(g: np.ndarray) -> np.ndarray:
    """Which rows of constraint values meet every constraint (≤ 0)."""
    return np.all(np.asarray(g) <= 0, axis=1)


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
