"""A run's checkpoint, checkpoint.pkl: where the run stood after its last generation, the evolution
with its random state included, for `resume` only.

It is a pickle, because the state is pymoo's whole NSGA-II object graph (population, survival,
mating, duplicate elimination, termination windows, the random generator) and nothing else gives
it back exactly: a resumed run must find the very front an uninterrupted one finds. It is a pickle
nobody can abuse:

- It is read by `_Unpickler`, which resolves only the (module, name) pairs in ALLOWED: the
  classes a checkpoint of this code holds, recorded by loading real checkpoints of every kind of
  run (generational and steady-state, one trajectory and several, every termination, keep all
  and front, with real episodes and with a scorer, every --algorithm and --objective-scaling).
  Each is a plain data class or a pure numeric function; none reaches the file system, a process
  or `exec`. A stranger's checkpoint naming anything else (os.system, builtins.eval,
  numpy.testing, ...) is refused before it is resolved, so no code of theirs runs.
- A plug-in optimiser (gainfarm.plugins' gainfarm.algorithms group) is pickled with the run, so
  its classes are in the checkpoint too. Its factory declares them, `checkpoint_globals`: exact
  (module, name) pairs under the same rule as ALLOWED. They are allowed only in the checkpoint
  of a run whose config.json names that algorithm, and resuming that run runs the plug-in's own
  code anyway: the allowlist grows by what the user already chose to run, never by a prefix, and
  a stranger's checkpoint still cannot name os.system, nor another plug-in's classes.
- It is two pickles: a header first (plain data only: no class at all may be resolved in it),
  then the state. The header holds the run id (records.RunIdentity): a checkpoint copied from
  another run is refused on its header, before its state is read at all.

A checkpoint of a run from before run ids is one pickle, the state alone. It is accepted only for
the run it was found in: when such a run is given its id, run.json keeps the checkpoint's SHA-256
(`legacy_checkpoint`), and the first checkpoint written after is of this format.
"""

import hashlib
import io
import pickle
from pathlib import Path
from typing import Any, ClassVar

from gainfarm import plugins
from gainfarm.analytic.tuning.records import RUN_ID, RunIdentity

FORMAT = "gainfarm checkpoint"
VERSION = 2

# Every global a checkpoint may name. Exact pairs, never module prefixes: a module that holds one
# harmless class may hold a harmful function next to it. Pickle can call any global it names with
# arguments of its choosing, so only names that are harmless to call belong here.
ALLOWED: frozenset[tuple[str, str]] = frozenset(
    {
        # the run's own types
        ("gainfarm.analytic.tuning.run", "RunState"),
        ("gainfarm.analytic.evaluators.replication", "Ran"),
        ("gainfarm.analytic.evaluators.replication", "Ledger"),
        ("gainfarm.schemas.episode", "Scores"),
        ("gainfarm.analytic.tuning.records", "HistoryRow"),
        ("gainfarm.analytic.tuning.records", "FrontMember"),
        ("gainfarm.analytic.tuning.evolution", "Evolution"),
        ("gainfarm.analytic.tuning.evolution", "FromTheDefaults"),
        # the built-in optimisers' own (analytic/tuning/algorithms/, one module each)
        ("gainfarm.analytic.tuning.algorithms.common", "GainProblem"),
        ("gainfarm.analytic.tuning.algorithms.random", "UniformRandom"),
        # --algorithm tpe. Not one of Optuna's classes: Study can be called with a storage URL
        # (a database on disk or the network), so the wrapper pickles plain data only (the points
        # and objectives told) and replays them into a new study when it is loaded.
        ("gainfarm.analytic.tuning.algorithms.tpe", "OptunaTPE"),
        ("gainfarm.analytic.tuning.algorithms.smsemoa", "_by_cv_and_domination"),
        ("gainfarm.analytic.tuning.algorithms.nsga3", "_by_cv_then_random"),
        ("gainfarm.analytic.tuning.search_space", "SearchSpace"),
        ("gainfarm.schemas.gains", "PDGains"),
        # numpy arrays, scalars and the random generator (numpy 2 names, then numpy 1's)
        ("numpy", "dtype"),
        ("numpy", "ndarray"),
        ("numpy", "sum"),  # a termination criterion's reduction, stored by reference
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "scalar"),
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy.random._pcg64", "PCG64"),
        ("numpy.random._pickle", "__bit_generator_ctor"),
        ("numpy.random._pickle", "__generator_ctor"),
        ("numpy.random.bit_generator", "SeedSequence"),
        ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"),
        # pymoo's NSGA-II, as analytic.evolution sets it up
        ("pymoo.algorithms.moo.nsga2", "NSGA2"),
        ("pymoo.algorithms.moo.nsga2", "binary_tournament"),
        # pymoo's other algorithms, as analytic.evolution sets them up (--algorithm)
        ("pymoo.algorithms.moo.age2", "AGEMOEA2"),
        ("pymoo.algorithms.moo.age2", "AGEMOEA2Survival"),
        ("pymoo.algorithms.moo.moead", "NeighborhoodSelection"),
        ("pymoo.algorithms.moo.moead", "ParallelMOEAD"),
        ("pymoo.algorithms.moo.nsga3", "HyperplaneNormalization"),
        ("pymoo.algorithms.moo.nsga3", "NSGA3"),
        ("pymoo.algorithms.moo.nsga3", "ReferenceDirectionSurvival"),
        ("pymoo.algorithms.moo.sms", "LeastHypervolumeContributionSurvival"),
        ("pymoo.algorithms.moo.sms", "SMSEMOA"),
        ("pymoo.core.duplicate", "NoDuplicateElimination"),
        ("pymoo.decomposition.tchebicheff", "Tchebicheff"),
        # and the parts every algorithm shares
        ("pymoo.core.callback", "Callback"),
        ("pymoo.core.duplicate", "DefaultDuplicateElimination"),
        ("pymoo.core.duplicate", "default_attr"),
        ("pymoo.core.evaluator", "Evaluator"),
        ("pymoo.core.individual", "Individual"),
        ("pymoo.core.initialization", "Initialization"),
        ("pymoo.core.mating", "Mating"),
        ("pymoo.core.population", "Population"),
        ("pymoo.core.problem", "ElementwiseEvaluationFunction"),
        ("pymoo.core.problem", "LoopedElementwiseEvaluation"),
        ("pymoo.core.repair", "NoRepair"),
        ("pymoo.core.variable", "Real"),
        ("pymoo.operators.crossover.sbx", "SBX"),
        ("pymoo.operators.mutation.pm", "PM"),
        ("pymoo.operators.sampling.rnd", "FloatRandomSampling"),
        ("pymoo.operators.selection.tournament", "TournamentSelection"),
        ("pymoo.operators.survival.rank_and_crowding.classes", "RankAndCrowding"),
        ("pymoo.operators.survival.rank_and_crowding.metrics", "FunctionalDiversity"),
        ("pymoo.operators.survival.rank_and_crowding.metrics", "calc_crowding_distance"),
        ("pymoo.core.termination", "NoTermination"),  # what an algorithm set up here holds
        ("pymoo.termination.cv", "ConstraintViolationTermination"),
        ("pymoo.termination.default", "DefaultMultiObjectiveTermination"),
        ("pymoo.termination.ftol", "MultiObjectiveSpaceTermination"),
        ("pymoo.termination.max_eval", "MaximumFunctionCallTermination"),
        ("pymoo.termination.max_gen", "MaximumGenerationTermination"),
        ("pymoo.termination.robust", "RobustTermination"),
        ("pymoo.termination.xtol", "DesignSpaceTermination"),
        ("pymoo.util.display.column", "Column"),
        ("pymoo.util.display.display", "Display"),
        ("pymoo.util.display.multi", "MultiObjectiveOutput"),
        ("pymoo.util.display.multi", "NumberOfNondominatedSolutions"),
        ("pymoo.util.display.output", "NumberOfEvaluations"),
        ("pymoo.util.display.output", "NumberOfGenerations"),
        ("pymoo.util.display.single", "AverageConstraintViolation"),
        ("pymoo.util.display.single", "MinimumConstraintViolation"),
        ("pymoo.util.nds.non_dominated_sorting", "NonDominatedSorting"),
        ("pymoo.util.sliding_window", "SlidingWindow"),
    }
)


class CheckpointRefused(ValueError):
    """A checkpoint this run will not resume from, said in one line naming the file."""


def encode(state: object, identity: RunIdentity) -> bytes:
    """checkpoint.pkl's content: the header, then the state."""
    header = {"format": FORMAT, "version": VERSION, "run_id": identity.run_id}
    return pickle.dumps(header) + pickle.dumps(state)


def decode(content: bytes, path: Path, identity: RunIdentity, algorithm: str | None = None) -> Any:
    """The state in checkpoint.pkl's `content`, if the checkpoint is of the run `identity`
    names; CheckpointRefused, naming `path`, if not, or if it is no checkpoint at all. `algorithm`
    is the run's (config.json's): a plug-in's declared globals are allowed too."""
    allowed = ALLOWED | plugin_globals(algorithm, path)
    stream = io.BytesIO(content)
    try:
        header = _Header(stream).load()
    except _NotAHeader:  # a state pickle without a header: from before run ids
        if hashlib.sha256(content).hexdigest() != identity.legacy_checkpoint:
            raise CheckpointRefused(
                f"{path}: a checkpoint without a run id, not the one this run "
                f"({identity.run_id}) had when it was given its id: refusing to resume from it"
            ) from None
        return _load(io.BytesIO(content), path, allowed)
    except CheckpointRefused:
        raise
    except Exception as error:  # a broken or foreign file: pickle may raise almost anything
        raise CheckpointRefused(f"{path}: not a gainfarm checkpoint ({_one_line(error)})") from None
    if not (
        isinstance(header, dict)
        and header.get("format") == FORMAT
        and isinstance(header.get("run_id"), str)
        and RUN_ID.fullmatch(header["run_id"])
    ):
        raise CheckpointRefused(f"{path}: not a gainfarm checkpoint (no header)")
    if header.get("version") != VERSION:
        raise CheckpointRefused(
            f"{path}: a checkpoint of format version {_one_line(header.get('version'))}; "
            f"this gainfarm reads version {VERSION}"
        )
    if header["run_id"] != identity.run_id:
        raise CheckpointRefused(
            f"{path}: the checkpoint of another run (run id {header['run_id']}), "
            f"not of this one ({identity.run_id}): refusing to resume from it"
        )
    return _load(stream, path, allowed)


def plugin_globals(algorithm: str | None, path: Path) -> frozenset[tuple[str, str]]:
    """The globals the plug-in optimiser `algorithm` declares its pickle names (none for a
    built-in one). CheckpointRefused, naming `path`, if it cannot be loaded or declares
    anything but (module, name) pairs of strings."""
    if algorithm is None or algorithm in plugins.builtin_names(plugins.ALGORITHMS):
        return frozenset()
    try:
        declared = getattr(plugins.load(plugins.ALGORITHMS, algorithm), "checkpoint_globals", ())
    except plugins.PluginError as error:
        raise CheckpointRefused(f"{path}: {error}") from None
    pairs = frozenset(tuple(pair) for pair in declared)
    if not all(len(pair) == 2 and all(isinstance(part, str) for part in pair) for pair in pairs):
        raise CheckpointRefused(
            f"{path}: algorithm {algorithm!r} declares checkpoint_globals that are not "
            "(module, name) pairs"
        )
    return pairs


def _load(stream: io.BytesIO, path: Path, allowed: frozenset[tuple[str, str]]) -> Any:
    try:
        return _Unpickler(stream, path, allowed).load()
    except CheckpointRefused:
        raise
    except Exception as error:
        raise CheckpointRefused(f"{path}: not a gainfarm checkpoint ({_one_line(error)})") from None


def _one_line(error: object) -> str:
    """A stranger's text, shown on one line and not too long."""
    text = " ".join(str(error).split())[:200]
    if not isinstance(error, Exception):
        return text
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


class _NotAHeader(Exception):
    pass


class _Header(pickle.Unpickler):
    """The header is plain data: any class at all in it means it is something else."""

    def find_class(self, module: str, name: str) -> Any:
        raise _NotAHeader


class _Unpickler(pickle.Unpickler):
    """Resolves the globals in ALLOWED (and those of the run's plug-in optimiser) and nothing
    else. Checkpoints written before a class moved name it where it was: before the built-in
    optimisers had a module each (analytic.tuning.evolution), before the run's row
    types moved to the records (analytic.figures), and before the project went under one import
    name, `gainfarm`, with analytic/ by role (analytic.run, schemas.gains, ...). MOVED maps those
    old places to today's, and only for the classes ALLOWED holds."""

    MOVED: ClassVar[dict[tuple[str, str], str]] = {
        ("analytic.figures", "HistoryRow"): "gainfarm.analytic.tuning.records",
        ("analytic.figures", "FrontMember"): "gainfarm.analytic.tuning.records",
        # Before the built-in optimisers had a module each, evolution.py held them all.
        **{
            (old, name): module
            for module, name in ALLOWED
            if module.startswith("gainfarm.analytic.tuning.algorithms.")
            for old in ("gainfarm.analytic.tuning.evolution", "analytic.evolution")
        },
        **{
            (
                module.removeprefix("gainfarm.")
                .replace(".tuning.", ".")
                .replace(".evaluators.", "."),
                name,
            ): module
            for module, name in ALLOWED
            if module.startswith("gainfarm.")
        },
    }

    def __init__(self, stream: io.BytesIO, path: Path, allowed: frozenset[tuple[str, str]]):
        super().__init__(stream)
        self.path = path
        self.allowed = allowed

    def find_class(self, module: str, name: str) -> Any:
        module = self.MOVED.get((module, name), module)
        if (module, name) not in self.allowed:
            named = " ".join(f"{module}.{name}".split())[:200]  # the stranger's text: one line
            raise CheckpointRefused(
                f"{self.path}: holds {named}, which no gainfarm checkpoint holds: "
                "refusing to load it"
            )
        return super().find_class(module, name)
