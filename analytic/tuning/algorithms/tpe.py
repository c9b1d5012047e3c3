"""Optuna's multi-objective TPE through Optuna's ask and tell (optuna: the moea extra)."""

import warnings
from typing import Any

import numpy as np
from pymoo.core.population import Population

from gainfarm.analytic.tuning.search_space import SearchSpace


class OptunaTPE:
    """The "tpe" algorithm: Optuna's multi-objective TPE (optuna.samplers.TPESampler) through
    Optuna's ask and tell, each decision variable a float between its bounds (already log10 of a
    gain: the search space is log-scaled). The first `pop_size` trials are uniform random (TPE's
    startup trials); every later one is sampled from Parzen estimators of the trials told:
    multivariate (the gains act together: a joint's damping is Kd against Kp), with the constant
    liar, Optuna's way with trials asked before others are told: a trial still running counts as
    a bad one, so that those in flight spread out rather than pile onto one mode.

    Generational, it asks `pop_size` trials at a time and is told them together: a generation of
    30 is then sampled from what the previous ones taught, none of it from the others in it.
    In a steady state (`steady_state`: the run's --async) it asks one trial at a time after the
    first generation and is told each as it returns, in any order: only the trials in flight (two
    per worker) are guessed by the liar, so TPE learns from every result as Optuna's own loop
    does (the way it is meant to run: one trial at a time).

    Deterministic and picklable without any of Optuna's objects: each ask is made of a fresh
    sampler seeded by (seed, asks made), so that the sampler carries no random state from one ask
    to the next (its other state, the search space, is derived from the trials). What is pickled
    is plain data: the seed, the asks made, every trial's point in trial number order, the
    objectives each told trial was told (None for a trial Optuna failed) and its constraint
    values; unpickling replays them into a new in-memory study (optuna.trial.create_trial,
    study.add_trials), which then asks exactly what the uninterrupted one would have. A trial
    asked and not yet told is replayed running (a generation is told after a resume), except in a
    steady state, whose candidates in flight a resumed run drops and asks anew: there it is
    replayed failed, which TPE leaves out, so no trial runs forever under the liar.
    """

    def __init__(
        self, pop_size: int, seed: int, space: SearchSpace, steady_state: bool = False
    ) -> None:
        self.pop_size = pop_size
        self.seed = seed
        self.steady_state = steady_state
        self.lower, self.upper = space.lower, space.upper
        self.names = tuple(f"log10_kp{j + 1}" for j in range(len(space.kp_low))) + tuple(
            f"log10_kd{j + 1}" for j in range(len(space.kd_low))
        )
        self.generations = 0  # asks made: a generation each, or one trial in a steady state
        self._points: list[list[float]] = []  # every trial's point, by trial number
        # The objectives each told trial was told (None: Optuna failed it), by trial number;
        # a trial asked and not in here is in flight.
        self._values: dict[int, list[float] | None] = {}
        self.pop = None  # no population: nothing for Evolution.correct to correct
        # Told constraints (Evolution sets `constrained`): each told trial's values, by number.
        self.constrained = False
        self._told_g: dict[int, list[float]] = {}
        self._live: dict[int, Any] = {}  # the Trials asked in this process, to be told
        self._study = self._new_study()

    def __getstate__(self) -> dict:
        state = {k: v for k, v in self.__dict__.items() if k not in ("_study", "_live")}
        if self.steady_state:  # in flight now, dropped by a resumed run: failed to it
            state["_values"] = {n: self._values.get(n) for n in range(len(self._points))}
        return state

    def __setstate__(self, state: dict) -> None:
        """Checkpoints from before constraints told none; from before a steady state kept the
        trials told (in trial number order: they were told in the order asked) apart from the
        trials asked."""
        state = {"constrained": False, "_told_g": {}, "steady_state": False, **state}
        if "_told" in state:
            told, asked = state.pop("_told"), state.pop("_asked")
            state["_points"] = [x for x, _ in told] + list(asked)
            state["_values"] = {number: values for number, (_, values) in enumerate(told)}
        self.__dict__.update({**state, "_live": {}})
        self._study = self._new_study()

    def rank_constraints(self, count: int) -> bool:
        """Rank by the constraints told (Evolution.constrain): TPE's constraints_func does."""
        self.constrained = bool(count)
        return True

    @property
    def pending(self) -> list[int]:
        """The numbers of the trials asked and not yet told, in the order asked."""
        return [n for n in range(len(self._points)) if n not in self._values]

    def _new_study(self) -> Any:
        """The study, with every trial told and asked so far replayed into it, in order."""
        optuna = _optuna()
        state = optuna.trial.TrialState
        distributions = {
            name: optuna.distributions.FloatDistribution(float(low), float(high))
            for name, low, high in zip(self.names, self.lower, self.upper, strict=True)
        }

        def replayed(number: int) -> tuple[Any, list[float] | None]:
            if number not in self._values:
                return state.RUNNING, None
            values = self._values[number]
            return (state.COMPLETE if values is not None else state.FAIL), values

        trials = []
        for number, x in enumerate(self._points):
            trial_state, values = replayed(number)
            trials.append(
                optuna.trial.create_trial(
                    state=trial_state,
                    params=dict(zip(self.names, x, strict=True)),
                    distributions=distributions,
                    values=values,
                    # What the constraints_func would have recorded had the trial been told here.
                    system_attrs={CONSTRAINTS_KEY: self._told_g[number]}
                    if number in self._told_g
                    else None,
                )
            )
        study = optuna.create_study(directions=["minimize", "minimize"])
        study.add_trials(trials)
        return study

    def _sampler(self, optuna: Any) -> Any:
        """This ask's sampler: seeded by (seed, asks made), nothing carried over."""
        seed = int(np.random.SeedSequence([self.seed, self.generations]).generate_state(1)[0])
        with warnings.catch_warnings():  # Optuna 4 calls both options experimental; 5 does not
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return optuna.samplers.TPESampler(
                seed=seed,
                n_startup_trials=self.pop_size,
                multivariate=True,
                constant_liar=True,
                # Optuna 5 reads a trial's constraints itself (Trial.set_constraint); 4 through
                # the constraints_func, which 5 deprecates.
                constraints_func=_trial_constraints
                if self.constrained and not _sets_constraints(optuna)
                else None,
            )

    def ask(self) -> Population:
        """A generation of trials; in a steady state, one after the first generation."""
        one = self.steady_state and self.generations > 0
        if self.pending and not self.steady_state:
            raise RuntimeError("ask() follows the tell() of the trials asked last")
        optuna = _optuna()
        self._study.sampler = self._sampler(optuna)
        asked = []
        for _ in range(1 if one else self.pop_size):
            trial = self._study.ask()
            self._live[trial.number] = trial
            asked.append(
                [
                    trial.suggest_float(name, float(low), float(high))
                    for name, low, high in zip(self.names, self.lower, self.upper, strict=True)
                ]
            )
        self._points += asked
        self.generations += 1
        return Population.new(X=np.array(asked, dtype=float))

    def tell(self, infills: Population) -> None:
        """The objectives (F) of trials asked: generationally, every one asked last, in the
        order asked; in a steady state, any of those in flight."""
        pending = self.pending
        x = infills.get("X").reshape(-1, len(self.names))
        if self.steady_state:
            numbers = [self._in_flight(row, pending) for row in x]
        elif len(x) == len(pending) and np.array_equal(
            x, np.array([self._points[n] for n in pending], dtype=float)
        ):
            numbers = pending
        else:
            raise ValueError("tell() takes the trials asked last, in the order asked")
        complete = _optuna().trial.TrialState.COMPLETE
        constraints = infills.get("G") if self.constrained else None
        replay = False
        for index, (number, f) in enumerate(zip(numbers, infills.get("F"), strict=True)):
            values = [float(value) for value in f]
            trial = self._live.pop(number, None)
            if constraints is not None:
                self._told_g[number] = [float(g) for g in constraints[index]]
                if trial is None:  # asked before a resume: replayed with its constraints below
                    replay = True
                elif _sets_constraints(_optuna()):
                    for key, g in enumerate(self._told_g[number]):
                        trial.set_constraint(str(key), g)  # the keys the replay's list gives
                else:  # read by the sampler's constraints_func as the trial is told
                    trial.set_user_attr(CONSTRAINTS_KEY, self._told_g[number])
            told = self._study.tell(trial if trial is not None else number, values)  # NaN: fails
            self._values[number] = values if told.state == complete else None
        if replay:
            self._study = self._new_study()

    def _in_flight(self, x: np.ndarray, pending: list[int]) -> int:
        """The number of the trial in flight asked at `x`; ValueError if none is."""
        for number in pending:
            if np.array_equal(x, self._points[number]):
                pending.remove(number)  # told once
                return number
        raise ValueError("tell() takes trials asked and not yet told")


# Optuna's own key for a trial's constraint values, as a list (Optuna 5 reads it too).
CONSTRAINTS_KEY = "constraints"


def _sets_constraints(optuna: Any) -> bool:
    """Whether this Optuna keeps a trial's constraints itself (5 does; 4 needs a function)."""
    return hasattr(optuna.trial.Trial, "set_constraint")


def _trial_constraints(trial: Any) -> list[float]:
    """TPE's constraints_func: the values tell() attached to the trial (≤ 0 met)."""
    return trial.user_attrs[CONSTRAINTS_KEY]


def _optuna() -> Any:
    """Optuna, quiet (it logs every trial at INFO); a ValueError if it is not installed."""
    try:  # optional extra: optuna (moea)
        import optuna
    except ImportError:
        raise ValueError(
            "algorithm tpe needs optuna: pip install optuna (gainfarm's moea extra)"
        ) from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna
