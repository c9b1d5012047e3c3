"""The conformance kit for an optimiser of the gainfarm.algorithms group: the checks gainfarm's
own built-ins pass, for a plug-in's author to run on theirs (docs/plugins.md, "Checking your
plug-in").

Either call the checks, each given the algorithm's name (registered or installed here), or
subclass `AlgorithmChecks` in a test module as pytest collects it:

    from gainfarm.testing.algorithms import AlgorithmChecks

    class TestHillClimb(AlgorithmChecks):
        algorithm = "hill_climb"

Each check runs the algorithm as a tuning run does, through the evolution loop
(analytic.tuning.evolution.Evolution), on a made-up problem (`toy_objectives`: no episode is
simulated), a small population for a few generations: seconds, cheap enough for any suite.
"""

from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from gainfarm.analytic.tuning.algorithms import STEADY_STATE
from gainfarm.analytic.tuning.checkpoint import decode, encode
from gainfarm.analytic.tuning.evolution import Evolution, optimiser
from gainfarm.analytic.tuning.records import RunIdentity
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.schemas.gains import PDGains

POP = 6  # small, yet enough for every built-in's mating (NSGA-II's tournament needs 4)
GENERATIONS = 3
SEED = 11


def toy_objectives(gains: PDGains) -> tuple[float, float]:
    """Two conflicting objectives of a candidate, from its gains alone (both positive, as an
    episode's are): stiffer is more accurate and less smooth."""
    x = np.log10(np.array(gains.kp + gains.kd))
    space = SearchSpace()
    share = float(np.mean((x - space.lower) / (space.upper - space.lower)))
    spread = float(np.std(x))
    return 0.01 + (1.0 - share) + 0.1 * spread, 0.01 + share**2 + 0.1 * spread


def generations(evolution: Evolution, count: int = GENERATIONS) -> list[list[PDGains]]:
    """`count` generations asked and told the toy objectives; the candidates asked in each."""
    asked = []
    for _ in range(count):
        candidates = evolution.ask()
        evolution.tell([toy_objectives(gains) for gains in candidates])
        asked.append(candidates)
    return asked


def check_asks_within_the_space(algorithm: str) -> None:
    """Each ask is a population of decision vectors (pop, dimensions) inside the search space,
    finite; told their objectives in the order asked, it asks again."""
    space = SearchSpace()
    made = optimiser(algorithm, POP, SEED, space)
    for generation in range(GENERATIONS):
        population = made.ask()
        x = np.asarray(population.get("X"), dtype=float)
        assert x.ndim == 2 and x.shape[1] == len(space.lower), (
            f"{algorithm}: generation {generation} asked X of shape {x.shape}, not "
            f"(n, {len(space.lower)})"
        )
        assert len(x) >= 1 and np.all(np.isfinite(x)), f"{algorithm}: asked no finite points"
        assert np.all(x >= space.lower) and np.all(x <= space.upper), (
            f"{algorithm}: generation {generation} asked points outside the search space"
        )
        population.set("F", np.array([toy_objectives(space.gains(row)) for row in x]))
        made.tell(infills=population)


def check_the_same_seed_asks_the_same(algorithm: str) -> None:
    """Two runs of one seed, told the same, ask the same candidates every generation; another
    seed asks others (a seed it ignores would make every repetition of an experiment one).
    A steady-state algorithm's single asks too."""
    first = generations(Evolution(POP, SEED, algorithm=algorithm))
    again = generations(Evolution(POP, SEED, algorithm=algorithm))
    assert first == again, f"{algorithm}: seed {SEED} asked otherwise the second time"
    other = generations(Evolution(POP, SEED + 1, algorithm=algorithm), 1)
    assert other[0] != first[0], f"{algorithm}: seeds {SEED} and {SEED + 1} asked the same"
    if algorithm in STEADY_STATE:
        asked = []
        for _ in range(2):
            evolution = Evolution(POP, SEED, algorithm=algorithm, steady_state=True)
            generations(evolution, 1)
            handle, gains = evolution.ask_one()
            evolution.tell_one(handle, toy_objectives(gains))
            asked.append([gains, evolution.ask_one()[1]])
        assert asked[0] == asked[1], f"{algorithm}: its steady state asked otherwise"


def check_a_checkpoint_continues_identically(algorithm: str, directory: Path) -> None:
    """Pickled through the run's checkpoint codec after every generation (its classes allowed:
    a plug-in declares them, `checkpoint_globals`) and read back, it asks and keeps the very
    candidates and front an uninterrupted run does."""
    whole = Evolution(POP, SEED, algorithm=algorithm, constraints=1)
    resumed = Evolution(POP, SEED, algorithm=algorithm, constraints=1)
    identity = RunIdentity.new()
    path = directory / "checkpoint.pkl"
    for generation in range(GENERATIONS):
        asked = whole.ask()
        assert resumed.ask() == asked, f"{algorithm}: generation {generation} asked otherwise"
        # Every other candidate breaks the constraint: the optimiser is told so, its own way.
        scores = [toy_objectives(gains) for gains in asked]
        violations = [[0.5 if index % 2 else -0.5] for index in range(len(asked))]
        whole.tell(scores, violations)
        resumed.tell(scores, violations)
        path.write_bytes(encode(resumed, identity))
        resumed = decode(path.read_bytes(), path, identity, algorithm)
    assert resumed.ask() == whole.ask(), f"{algorithm}: the resumed run asked otherwise"
    assert resumed.front() == whole.front(), f"{algorithm}: the resumed run's front differs"


class AlgorithmChecks:
    """The checks as pytest tests: subclass it as Test..., naming the algorithm (`algorithm`),
    or override the `algorithm` fixture (parametrised, to check several)."""

    algorithm: ClassVar[str]

    @pytest.fixture(name="algorithm")
    def _algorithm(self) -> str:
        return self.algorithm

    def test_asks_within_the_space(self, algorithm: str) -> None:
        check_asks_within_the_space(algorithm)

    def test_the_same_seed_asks_the_same(self, algorithm: str) -> None:
        check_the_same_seed_asks_the_same(algorithm)

    def test_a_checkpoint_continues_identically(self, algorithm: str, tmp_path: Path) -> None:
        check_a_checkpoint_continues_identically(algorithm, tmp_path)
