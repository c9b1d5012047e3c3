"""What a tuning run holds as it goes: its state (RunState, all a checkpoint keeps, so a resumed
run continues exactly where it stood), where it stands for a progress line (RunProgress), and
the evolution its config starts from (`evolution_of`)."""

import secrets
from dataclasses import dataclass, field

from gainfarm.analytic.evaluators.replication import Ledger, Ran
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import Evolution
from gainfarm.analytic.tuning.records import HistoryRow
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.limits import MEASURES, before_lag


@dataclass
class RunState:
    """What a checkpoint holds: enough to continue exactly where the run stood."""

    evolution: Evolution
    history: list[HistoryRow] = field(default_factory=list)
    evaluated: list[tuple[float, float]] = field(default_factory=list)
    # Each evaluated candidate's safety measures (schemas.limits.measures), in the same order.
    measured: list[tuple[float, ...]] = field(default_factory=list)
    episodes: dict[PDGains, list[str]] = field(default_factory=dict)  # job ids of kept logs
    wall_seconds: float = 0.0
    stopped: str | None = None
    serial: int = 0  # steady-state candidates asked so far: their job ids' numbers
    busy_seconds: float = 0.0  # workers' time on this run's episodes (simulate + encode)
    # Each candidate's episodes as they ran (who, the log's SHA-256, the scores), and the job ids
    # of those the referee has run again (analytic.evaluators.replication).
    provenance: dict[PDGains, tuple[Ran, ...]] = field(default_factory=dict)
    validated: set[str] = field(default_factory=set)
    # How each validated episode was checked: job id -> (Check, Ruling, the worker that ran it).
    checks: dict[str, tuple[str, str, str]] = field(default_factory=dict)
    ledger: Ledger = field(default_factory=Ledger)  # what validation cost and found
    # The key of the spot checks' draw: never leaves this process, so no worker can tell which
    # of its episodes will be checked; kept, so a resumed run draws as it would have.
    spot_key: bytes = field(default_factory=lambda: secrets.token_bytes(16))
    # The spot checks' rate, fixed as the run first starts (RunConfig.spot_checks, or sized for
    # the farm it starts on) and kept, so a resumed run draws as it would have; and what it was
    # sized on: the episodes the run plans and the farm's workers then.
    spot_rate: float | None = None
    spot_plan: tuple[int, int] | None = None
    rewinds: int = 0  # times the evolution started again without a caught worker's results
    unchecked: str = ""  # why the front's episodes are not refereed (trusted, or switched off)
    lag_measured: bool = True  # `measured` holds the lag (False: a checkpoint from before it)

    def __setstate__(self, state: dict) -> None:
        """Checkpoints from before validation by a referee have nothing validated yet."""
        defaults = {
            "provenance": {},
            "validated": set(),
            "checks": {},
            "ledger": Ledger(),
            "spot_key": secrets.token_bytes(16),
            "spot_rate": None,
            "spot_plan": None,
            "rewinds": 0,
            "unchecked": "",
        }
        self.__dict__.update({**defaults, **state})
        if "measured" not in state:  # from before the limits: its points count as within them
            self.measured = [(0.0,) * len(MEASURES) for _ in self.evaluated]
        elif not state.get("lag_measured", False):  # from before the lag: its points had none
            self.measured = [before_lag(values) for values in self.measured]
        self.lag_measured = True


# Pickled under the name every checkpoint has given it (analytic.tuning.checkpoint's ALLOWED),
# from before it moved here: analytic.tuning.run, which imports it, so that name still resolves
# and checkpoints written before and after the move read alike.
RunState.__module__ = "gainfarm.analytic.tuning.run"


@dataclass(frozen=True)
class RunProgress:
    """Where a run stands, after each evaluation and once more as each generation ends (with
    `ended`; its records and checkpoint are written at most every RECORD_SECONDS, and as the run
    stops): for a progress line. `generation` counts the
    generations ended; `hypervolume` and `best_f_acc` are the last ended one's (NaN before)."""

    generation: int
    evaluations: int
    hypervolume: float
    best_f_acc: float
    elapsed: float
    ended: bool = False
    # The evaluations the run's budget allows (--evaluations, or --generations times the
    # population); None when it stops on convergence, whose moment cannot be known ahead.
    budget: int | None = None
    # For a run that stops on convergence, the evaluations at which it is expected to: a fit of
    # its hypervolume's course (termination.expected_generations); None without one.
    expected: int | None = None


def evolution_of(config: RunConfig) -> Evolution:
    """The evolution a run of `config` starts from (and starts again from, after a rewind)."""
    return Evolution(
        config.pop,
        config.seed,
        space=config.space,
        steady_state=config.asynchronous,
        algorithm=config.algorithm,
        objective_scaling=config.objective_scaling,
        reference=config.reference_point,
        constraints=config.limits.count,
        from_defaults=config.from_defaults,
        defaults=config.default_gains,
    )
