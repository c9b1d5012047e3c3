"""A run directory's records: the row types and the files that hold them, written and read.

The layout of every file a run writes lives here and only here, so the writer of a run and every
reader of it (the experiments, the dataset, a user's script) agree. Floats are written repr-exact
(shortest round-tripping form), so reading a file back gives the very same numbers and two
identical runs give byte-identical files. Each file appears whole or not at all (through
`edges.files.write_atomically`).

    config.json     the RunConfig (analytic.config)
    run.json        the run's identity (RunIdentity): a random id, which its checkpoint carries
    run.lock        held by the one process writing the run (edges.files.Lock); says which
    history.csv     one HistoryRow per generation
    front.csv       the front: one FrontMember per line, most accurate first; `diverged` says
                    which members' objectives are a divergence penalty, not a measurement
    front.json      the front again, each member with the episode logs it left (the index the
                    dataset reads; as evaluations.json is for a batch) and its episodes'
                    provenance, and what validation found over the run
    provenance.csv  one line per episode of each front member: which worker ran it and how the
                    referee checked it (front.csv's side file: its `member` is the row there)
    evaluated.csv   every candidate's objectives, in the order told: the cloud behind the front;
                    and its safety measures (schemas.limits) and whether they met the limits
    baseline.json   the default gains' point on the run's trajectories, evaluated once when
                    the run reports: what the tuned controllers are measured against
    checkpoint.pkl  the evolution's own state, for `analytic resume` only (analytic.checkpoint)
"""

import csv
import dataclasses
import io
import json
import math
import operator
import re
import secrets
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import declarations
from gainfarm.analytic.tuning.declared import maximised as maximised_among
from gainfarm.schemas.documents import load_json, read_bounded
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.limits import BEFORE_LAG, DAMPING, MEASURED, Limits, named
from gainfarm.schemas.objectives import Objective
from gainfarm.schemas.robot import MAX_JOINTS, N_JOINTS
from gainfarm.schemas.trajectory import KIND_PATTERN

# The names a run directory uses; the report links to the figures by these relative names.
PARETO_PNG = "pareto.png"
HYPERVOLUME_PNG = "hypervolume.png"
FRONT_CSV = "front.csv"
HISTORY_CSV = "history.csv"
REPORT_MD = "report.md"
FRONT_JSON = "front.json"
PROVENANCE_CSV = "provenance.csv"
EVALUATED_CSV = "evaluated.csv"
BASELINE_JSON = "baseline.json"
CONFIG_JSON = "config.json"
RUN_JSON = "run.json"
FEEDFORWARD = "feedforward.npz"  # the learned model a run's episodes add to their PD, if any
LOCK = "run.lock"
EPISODES = "episodes"

# The columns of the run's objectives are named after them (RunConfig.objectives): f_acc and f_t
# in the paper's run, so its files read as they did before objectives could be chosen. Each
# holds the objective in its own sense (a maximised one as it is, not as the optimiser is told).
HISTORY_LEAD = ("generation", "evaluations", "hypervolume")


def gains_fields(joints: int = N_JOINTS) -> tuple[str, ...]:
    """The gains' columns of a robot of `joints` joints: kp1..kpN, then kd1..kdN (the iiwa
    14's seven by default, as every run before other arms wrote them)."""
    return (
        *(f"kp{joint}" for joint in range(1, joints + 1)),
        *(f"kd{joint}" for joint in range(1, joints + 1)),
    )


GAINS_FIELDS = gains_fields()


def history_fields(names: Sequence[str] = DEFAULT_OBJECTIVES) -> tuple[str, ...]:
    """history.csv's header: the best of each objective is `best_<name>`."""
    return (*HISTORY_LEAD, *(f"best_{name}" for name in names), "wall_seconds")


def front_fields(
    names: Sequence[str] = DEFAULT_OBJECTIVES, joints: int = N_JOINTS
) -> tuple[str, ...]:
    """front.csv's header for a robot of `joints` joints (before the `diverged` column, a
    front.csv was read as members none of whose episodes diverged)."""
    return (*gains_fields(joints), *names, "diverged")


HISTORY_FIELDS = history_fields()
FRONT_FIELDS = front_fields()


@dataclass(frozen=True)
class HistoryRow:
    """One generation of a run, one line of history.csv.

    `evaluations` and `wall_seconds` are cumulative since the start of the run; `best` is the
    best value of each of the run's objectives (`names`) found so far, in its own sense and unit.
    """

    generation: int
    evaluations: int
    hypervolume: float
    best: tuple[float, ...]
    wall_seconds: float
    names: tuple[str, ...] = DEFAULT_OBJECTIVES

    def __post_init__(self) -> None:
        # Normalise numpy scalars to Python numbers: repr(np.float64(1.0)) is "np.float64(1.0)",
        # which would corrupt the CSV, and equality with rows read back should just work.
        # operator.index refuses a float generation rather than silently truncating it.
        object.__setattr__(self, "generation", operator.index(self.generation))
        object.__setattr__(self, "evaluations", operator.index(self.evaluations))
        for name in ("hypervolume", "wall_seconds"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "best", tuple(float(value) for value in self.best))
        object.__setattr__(self, "names", tuple(self.names))
        if len(self.best) != len(self.names):
            raise ValueError(f"{len(self.best)} best values for objectives {self.names}")

    def __setstate__(self, state: dict[str, Any]) -> None:
        """A checkpoint from before objectives were named pickled `best_f_acc` and `best_f_t`:
        the run's first and second objectives' best."""
        state = dict(state)
        if "best_f_acc" in state:
            state["best"] = (state.pop("best_f_acc"), state.pop("best_f_t"))
            state.setdefault("names", DEFAULT_OBJECTIVES)
        self.__dict__.update(state)

    # The best of the paper's two by name, where the run has them (AttributeError where not).
    @property
    def best_f_acc(self) -> float:
        return self._best("f_acc")

    @property
    def best_f_t(self) -> float:
        return self._best("f_t")

    def _best(self, name: str) -> float:
        if name not in self.names:
            raise AttributeError(f"the run's objectives are {', '.join(self.names)}, not {name}")
        return self.best[self.names.index(name)]


@dataclass(frozen=True)
class EpisodeCheck:
    """One episode of a front member: the worker that ran it, and how it was checked.

    `check`: "refereed" (the referee, this process, ran it again before the run reported its
    front), "spot-checked" (drawn at random as it returned, and run again), or "not checked".
    `ruling`: the referee's, "agreed" (the same log bit for bit, the same scores),
    "contradicted" (the referee's run stands, and the worker is distrusted) or "unsettled" (the
    referee could not run it: the episode counts as failed); for one not checked, why not.
    """

    job_id: str
    worker: str
    check: str
    ruling: str


PROVENANCE_FIELDS = ("member", "job_id", "worker", "check", "ruling")


@dataclass(frozen=True)
class ValidationRecord:
    """What validation found over a run, as front.json and report.md say it: episodes the
    referee ran again (the front's, and the spot checks'), how many disagreed or could not be
    rerun, the workers distrusted with the evidence against each, and how often the evolution
    started again without a caught worker's results. `unchecked`: why nothing was checked.
    `spot_check_guarantee`: what the spot checks' rate buys, in words; `failures_checked`: the
    failures workers claimed that the referee ran too; `baseline_refereed` and
    `held_out_refereed`: the default gains' episodes and the held-out check's it ran again."""

    refereed: int = 0
    spot_checked: int = 0
    spot_check_rate: float = 0.0
    spot_check_guarantee: str = ""
    failures_checked: int = 0
    baseline_refereed: int = 0
    held_out_refereed: int = 0
    disagreements: int = 0
    unsettled: int = 0
    distrusted: dict[str, str] = field(default_factory=dict)
    rewinds: int = 0
    unchecked: str = ""


class NamedObjectives:
    """A point's objectives by name (a front member's, the default gains'): `objectives` as the
    optimiser saw them, `names` and `maximised` the run's."""

    objectives: tuple[float, ...]
    names: tuple[str, ...]
    maximised: tuple[str, ...]

    @property
    def named(self) -> dict[str, float]:
        """Its objectives by name, each in its own sense: `member.named["f_acc"]`."""
        return {
            name: -value if name in self.maximised else value
            for name, value in zip(self.names, self.objectives, strict=True)
        }

    # The paper's two by name, where the run has them (AttributeError where it has not).
    @property
    def f_acc(self) -> float:
        return self._by_name("f_acc")

    @property
    def f_t(self) -> float:
        return self._by_name("f_t")

    def _by_name(self, name: str) -> float:
        found = self.named
        if name not in found:
            raise AttributeError(f"the run's objectives are {', '.join(self.names)}, not {name}")
        return found[name]


@dataclass(frozen=True)
class FrontMember(NamedObjectives):
    """One non-dominated controller, one line of front.csv: its 14 gains and its objectives.

    `objectives` are as the optimiser was told them (a maximised one negated), in the order of
    `names`, the run's (RunConfig.objectives); `named` gives them by name, each in its own sense
    and unit (the paper's f_acc in metres, f_t in (N·m)²). `diverged`: an episode of the member
    was stopped early, so its objectives carry the divergence penalty (schemas.objectives) and
    measure no tracking; an experiment leaves such points out of its normalisation
    (analytic.experiments).
    Gains may be given as any sequence (a numpy row, say); they are stored as tuples of Python
    floats so members compare and hash by value. `logs` are the member's kept episode logs,
    relative to the run directory, one per trajectory whose episode ran (front.json holds them,
    front.csv does not; they take no part in comparisons).
    """

    kp: tuple[float, ...]
    kd: tuple[float, ...]
    objectives: tuple[float, ...]
    logs: tuple[str, ...] = field(default=(), compare=False)
    diverged: bool = False
    episodes: tuple[EpisodeCheck, ...] = field(default=(), compare=False)  # their provenance
    # Its safety measures, worst over its episodes, in schemas.limits.MEASURED's order, its least
    # damping ratio last (front.json holds them; empty for a run from before the limits, without
    # the damping for one from before it): the front holds only those within the run's limits.
    measures: tuple[float, ...] = field(default=(), compare=False)
    names: tuple[str, ...] = DEFAULT_OBJECTIVES
    maximised: tuple[str, ...] = field(default=(), compare=False)  # those of `names` that are

    def __post_init__(self) -> None:
        for name in ("kp", "kd"):
            gains = tuple(float(gain) for gain in getattr(self, name))
            if not 1 <= len(gains) <= MAX_JOINTS:
                raise ValueError(f"{name} needs one gain per joint, got {len(gains)}")
            object.__setattr__(self, name, gains)
        if len(self.kp) != len(self.kd):
            raise ValueError(f"kp has {len(self.kp)} gains and kd {len(self.kd)}: one per joint")
        _set_objectives(self)
        if not isinstance(self.diverged, bool):
            raise ValueError(f"diverged must be true or false, got {self.diverged!r}")
        object.__setattr__(self, "logs", tuple(str(path) for path in self.logs))
        object.__setattr__(self, "measures", tuple(float(value) for value in self.measures))

    @property
    def gains(self) -> PDGains:
        return PDGains(kp=self.kp, kd=self.kd)


def _set_objectives(point: Any) -> None:
    """A front member's or baseline's objectives and names, checked and made plain floats."""
    object.__setattr__(point, "objectives", tuple(float(value) for value in point.objectives))
    object.__setattr__(point, "names", tuple(point.names))
    object.__setattr__(point, "maximised", tuple(point.maximised))
    if len(point.objectives) != len(point.names):
        raise ValueError(f"{len(point.objectives)} objective values for {point.names}")
    if not set(point.maximised) <= set(point.names):
        raise ValueError(f"maximised {point.maximised} are not among the objectives {point.names}")


def _told(names: Sequence[str], values: Sequence[float]) -> tuple[float, ...]:
    """Values in their own sense (a file's) as the optimiser is told them: the objectives'
    declarations say which are maximised."""
    return tuple(
        objective.minimised(float(value))
        for objective, value in zip(declarations(names), values, strict=True)
    )


def best_of(points: Sequence[Sequence[float]], names: Sequence[str]) -> tuple[float, ...]:
    """The best of each objective over `points` (as told), in its own sense: a HistoryRow's
    `best` (NaN while there is no point: no candidate feasible yet)."""
    return tuple(
        objective.minimised(min((point[index] for point in points), default=math.nan))
        for index, objective in enumerate(declarations(names))
    )


def _exact(value: float) -> str:
    """The shortest text that reads back as exactly `value` (float's repr), numpy-proof."""
    return repr(float(value))


def _nan_last(value: float) -> tuple[bool, float]:
    """A sort key that puts NaN after every number instead of scrambling the order."""
    return (math.isnan(value), value)


def _front_order(member: FrontMember) -> tuple:
    """The first objective, then the second, then the gains: a total order, so equal fronts
    give equal files."""
    return (*map(_nan_last, member.objectives), member.kp, member.kd)


def sorted_front(front: Iterable[FrontMember]) -> list[FrontMember]:
    """The front in the order every output shows it: most accurate first."""
    return sorted(front, key=_front_order)


def _csv_bytes(header: Sequence[str], rows: Iterable[Sequence[str]]) -> bytes:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return buffer.getvalue().encode("utf-8")


def history_csv(history: Sequence[HistoryRow], names: Sequence[str] | None = None) -> bytes:
    """history.csv's content, rows in the order given (the order the generations ran); `names`:
    the run's objectives, if there is no row to say them."""
    names = names or (history[0].names if history else DEFAULT_OBJECTIVES)
    return _csv_bytes(
        history_fields(names),
        (
            (
                str(row.generation),
                str(row.evaluations),
                _exact(row.hypervolume),
                *map(_exact, row.best),
                _exact(row.wall_seconds),
            )
            for row in history
        ),
    )


def front_csv(
    front: Sequence[FrontMember], names: Sequence[str] | None = None, joints: int = N_JOINTS
) -> bytes:
    """front.csv's content, sorted by the first objective then the second so equal fronts give
    byte-identical files; `names` and `joints`: the run's objectives and its robot's joint count,
    if there is no member to say them."""
    names = names or (front[0].names if front else DEFAULT_OBJECTIVES)
    joints = len(front[0].kp) if front else joints
    return _csv_bytes(
        front_fields(names, joints),
        (
            (
                *map(_exact, member.kp),
                *map(_exact, member.kd),
                *map(_exact, member.named.values()),
                str(member.diverged).lower(),
            )
            for member in sorted_front(front)
        ),
    )


def _read_rows(path: Path, fields: Sequence[str], *legacy: Sequence[str]) -> list[dict[str, str]]:
    """The rows of a CSV, refusing one whose header is not exactly `fields` (another format),
    or one of `legacy`, the headers older versions wrote."""
    with Path(path).open(newline="", encoding="utf-8") as stream:
        reader = csv.DictReader(stream)
        headers = {tuple(fields), *(tuple(header) for header in legacy)}
        if tuple(reader.fieldnames or ()) not in headers:
            raise ValueError(
                f"{path}: expected columns {','.join(fields)}, got {reader.fieldnames}"
            )
        return list(reader)


def _objective_columns(
    path: Path, lead: Sequence[str], trails: Sequence[Sequence[str]], prefix: str = ""
) -> tuple[str, ...]:
    """The objectives a CSV's header names, between its `lead` columns and one of its `trails`
    (the longest that fits), each `prefix` + a name: the paper's if the header is of no such
    form (then `_read_rows` refuses it, naming what it expected)."""
    with Path(path).open(newline="", encoding="utf-8") as stream:
        header = next(csv.reader(stream), [])
    if tuple(header[: len(lead)]) != tuple(lead):
        return DEFAULT_OBJECTIVES
    for trail in sorted(trails, key=len, reverse=True):
        middle = header[len(lead) : len(header) - len(trail)]
        if tuple(header[len(header) - len(trail) :]) == tuple(trail) and len(middle) == len(
            DEFAULT_OBJECTIVES
        ):
            names = tuple(column.removeprefix(prefix) for column in middle)
            if all(
                column.startswith(prefix) and re.fullmatch(KIND_PATTERN, name)
                for column, name in zip(middle, names, strict=True)
            ):
                return names
    return DEFAULT_OBJECTIVES


def _flag(text: str, path: Path) -> bool:
    if text not in ("true", "false"):
        raise ValueError(f"{path}: diverged must be true or false, got {text!r}")
    return text == "true"


def read_history(path: Path) -> list[HistoryRow]:
    """history.csv as written by `history_csv`, in file order."""
    names = _objective_columns(path, HISTORY_LEAD, [("wall_seconds",)], prefix="best_")
    return [
        HistoryRow(
            generation=int(row["generation"]),
            evaluations=int(row["evaluations"]),
            hypervolume=float(row["hypervolume"]),
            best=tuple(float(row[f"best_{name}"]) for name in names),
            wall_seconds=float(row["wall_seconds"]),
            names=names,
        )
        for row in _read_rows(path, history_fields(names))
    ]


def read_front(path: Path) -> list[FrontMember]:
    """front.csv as written by `front_csv`, in file order (already sorted by the first
    objective); its objectives and its robot's joint count are the header's."""
    joints = front_joints(path)
    names = _objective_columns(path, gains_fields(joints), [("diverged",), ()])
    maximised = maximised_among(names)
    fields = front_fields(names, joints)
    return [
        FrontMember(
            kp=tuple(float(row[f"kp{joint}"]) for joint in range(1, joints + 1)),
            kd=tuple(float(row[f"kd{joint}"]) for joint in range(1, joints + 1)),
            objectives=_told(names, [row[name] for name in names]),
            diverged=_flag(row.get("diverged", "false"), path),
            names=names,
            maximised=maximised,
        )
        for row in _read_rows(path, fields, fields[:-1])
    ]


def front_joints(path: Path) -> int:
    """The joint count a front.csv's header names (its kp1..kpN, kd1..kdN columns); the iiwa
    14's seven for a header of no such form (then `read_front` refuses it, naming what it
    expected)."""
    with Path(path).open(newline="", encoding="utf-8") as stream:
        header = next(csv.reader(stream), [])
    joints = 0
    while joints < len(header) and header[joints] == f"kp{joints + 1}":
        joints += 1
    whole = tuple(header[: 2 * joints]) == gains_fields(joints)  # kd1..kdN follow
    return joints if whole and 1 <= joints <= MAX_JOINTS else N_JOINTS


# evaluated.csv's columns after the objectives', and those of the versions before.
EVALUATED_TRAILS = (
    (*MEASURED, "feasible"),
    (),  # before the limits: the objectives alone
    (*BEFORE_LAG, "feasible"),  # before the damping margin
    (*BEFORE_LAG, DAMPING, "feasible"),  # before the lag
)


def evaluated_fields(names: Sequence[str] = DEFAULT_OBJECTIVES) -> tuple[str, ...]:
    """evaluated.csv's header: the objectives, the safety measures, whether they are within the
    limits."""
    return (*names, *EVALUATED_TRAILS[0])


EVALUATED_FIELDS = evaluated_fields()


def evaluated_csv(
    points: Sequence[tuple[float, ...]],
    measured: Sequence[Sequence[float]],
    limits: Limits,
    objectives: Sequence[Objective] | None = None,
) -> bytes:
    """evaluated.csv's content: each candidate's objectives as told (`points`), written in their
    own sense under their names (`objectives`: the run's declarations, the paper's by default),
    its safety measures and whether they are within `limits`, in the order told."""
    objectives = objectives or declarations()
    return _csv_bytes(
        evaluated_fields([objective.name for objective in objectives]),
        (
            (
                *(
                    _exact(objective.minimised(value))
                    for objective, value in zip(objectives, point, strict=True)
                ),
                *map(_exact, values),
                str(not limits.violated(values)).lower(),
            )
            for point, values in zip(points, measured, strict=True)
        ),
    )


def _evaluated_rows(path: Path) -> tuple[tuple[str, ...], list[dict[str, str]]]:
    names = _objective_columns(path, (), EVALUATED_TRAILS)
    legacy = [(*names, *trail) for trail in EVALUATED_TRAILS[1:]]
    return names, _read_rows(path, evaluated_fields(names), *legacy)


def read_evaluated(path: Path) -> list[tuple[float, ...]]:
    """evaluated.csv's objectives as the optimiser was told them, in the order told."""
    names, rows = _evaluated_rows(path)
    return [_told(names, [row[name] for name in names]) for row in rows]


def evaluated_names(path: Path) -> tuple[str, ...]:
    """The objectives evaluated.csv's header names."""
    return _objective_columns(path, (), EVALUATED_TRAILS)


def read_measured(path: Path) -> list[tuple[float, ...]]:
    """evaluated.csv's safety measures, in MEASURED's order, in the order told (none in a run
    from before them; without the damping in one from before it, the lag 0.0 in one from before
    it: schemas.limits.named)."""
    _, rows = _evaluated_rows(path)
    return [named(row) for row in rows if "feasible" in row]


def front_json(front: Sequence[FrontMember], validation: ValidationRecord | None = None) -> bytes:
    """front.json's content: the front in front.csv's order, each member with its logs and its
    episodes' provenance, and what validation found (if given)."""
    members = [
        {
            "kp": list(member.kp),
            "kd": list(member.kd),
            **member.named,
            "diverged": member.diverged,
            "logs": list(member.logs),
            "episodes": [dataclasses.asdict(episode) for episode in member.episodes],
            # A member of a run from before the damping margin has one measure fewer.
            "measures": dict(zip(MEASURED, member.measures, strict=False)),
        }
        for member in sorted_front(front)
    ]
    content: dict[str, object] = {"members": members}
    names = front[0].names if front else DEFAULT_OBJECTIVES
    if names != DEFAULT_OBJECTIVES:  # the paper's run's front.json as it was without it
        content["objectives"] = list(names)
    if validation is not None:
        content["validation"] = dataclasses.asdict(validation)
    return json.dumps(content, indent=1).encode()


# A run's own records (config.json, front.json, ...) are a few MB at most; read back by every
# command on a run, and refused past this (BadDocument, a ValueError) as any file given to one.
MAX_RECORD_BYTES = 256 << 20


def read_record(path: Path) -> Any:
    """A JSON record of a run, read within MAX_RECORD_BYTES and schemas.documents' nesting."""
    return load_json(read_bounded(Path(path), MAX_RECORD_BYTES))


def read_front_json(path: Path) -> list[FrontMember]:
    """front.json as written by `front_json`; ValueError if it is not one."""
    try:
        record = read_record(path)
        names = tuple(record.get("objectives", DEFAULT_OBJECTIVES))
        maximised = maximised_among(names)
        return [
            FrontMember(
                **{k: v for k, v in member.items() if k not in ("episodes", "measures", *names)},
                objectives=_told(names, [member[name] for name in names]),
                episodes=tuple(EpisodeCheck(**episode) for episode in member.get("episodes", ())),
                measures=named(member.get("measures", {})),
                names=names,
                maximised=maximised,
            )
            for member in record["members"]
        ]
    except (KeyError, TypeError, AttributeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: not a front.json ({error})") from None


def read_validation(path: Path) -> ValidationRecord | None:
    """What validation found, as front.json says it (None if it says nothing: an older run)."""
    try:
        found = read_record(path).get("validation")
        return None if found is None else ValidationRecord(**found)
    except (TypeError, AttributeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: not a front.json ({error})") from None


def provenance_csv(front: Sequence[FrontMember]) -> bytes:
    """provenance.csv's content: each front member's episodes, by the member's front.csv row."""
    return _csv_bytes(
        PROVENANCE_FIELDS,
        (
            (str(row), episode.job_id, episode.worker, episode.check, episode.ruling)
            for row, member in enumerate(sorted_front(front), start=1)
            for episode in member.episodes
        ),
    )


@dataclass(frozen=True)
class Baseline(NamedObjectives):
    """The default gains' objectives on a run's trajectories, as the run's candidates are
    scored (the same weights), one line of baseline.json. `diverged`: an episode was stopped
    early or could not run, so the point is a penalty. `episodes`: each trajectory's job id,
    status and scores, for the record (no part in comparisons)."""

    gains: PDGains
    objectives: tuple[float, ...]  # as told, in the order of `names` (FrontMember's)
    diverged: bool
    episodes: tuple[dict, ...] = field(default=(), compare=False)
    names: tuple[str, ...] = DEFAULT_OBJECTIVES
    maximised: tuple[str, ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        _set_objectives(self)


def baseline_json(baseline: Baseline) -> bytes:
    """baseline.json's content."""
    return json.dumps(
        {
            "gains": baseline.gains.model_dump(),
            **baseline.named,
            "diverged": baseline.diverged,
            "episodes": list(baseline.episodes),
            # the paper's run's baseline.json as it was without it
            **({} if baseline.names == DEFAULT_OBJECTIVES else {"objectives": baseline.names}),
        },
        indent=1,
    ).encode()


def read_baseline(path: Path) -> Baseline:
    """baseline.json as written by `baseline_json`; ValueError naming it if it is not one."""
    try:
        fields = read_record(path)
        names = tuple(fields.get("objectives", DEFAULT_OBJECTIVES))
        return Baseline(
            gains=PDGains.model_validate(fields["gains"]),
            objectives=_told(names, [float(fields[name]) for name in names]),
            diverged=bool(fields["diverged"]),
            episodes=tuple(fields.get("episodes", ())),
            names=names,
            maximised=maximised_among(names),
        )
    except (KeyError, TypeError, ValueError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not a baseline.json ({error})") from None


RUN_ID = re.compile(r"[0-9a-f]{32}")


@dataclass(frozen=True)
class RunIdentity:
    """Which run a directory holds, as run.json says: a random id, given when the run was created
    (a run from before run ids gets one when it is first opened), which its checkpoint must
    carry. Not part of the RunConfig: two runs of one configuration are still two runs."""

    run_id: str
    # A run from before run ids: the SHA-256 of the id-less checkpoint it had when it got its id,
    # the one id-less checkpoint it accepts (analytic.checkpoint).
    legacy_checkpoint: str | None = None

    @classmethod
    def new(cls, legacy_checkpoint: str | None = None) -> "RunIdentity":
        return cls(secrets.token_hex(16), legacy_checkpoint)


def run_json(identity: RunIdentity) -> bytes:
    """run.json's content."""
    fields = {"run_id": identity.run_id}
    if identity.legacy_checkpoint is not None:
        fields["legacy_checkpoint"] = identity.legacy_checkpoint
    return json.dumps(fields, indent=1).encode()


def read_identity(path: Path) -> RunIdentity:
    """run.json as written by `run_json`; ValueError naming it if it is not one."""
    try:
        fields = read_record(path)
        identity = RunIdentity(fields["run_id"], fields.get("legacy_checkpoint"))
    except (KeyError, TypeError, AttributeError, UnicodeDecodeError, json.JSONDecodeError):
        identity = None
    if identity is None or not (
        isinstance(identity.run_id, str)
        and RUN_ID.fullmatch(identity.run_id)
        and isinstance(identity.legacy_checkpoint, str | None)
    ):
        raise ValueError(f"{path}: not a run.json (a run id of 32 hex digits)")
    return identity


@dataclass(frozen=True)
class RunRecord:
    """What a run directory says about its run, read from its plain files alone (no pickle):
    enough to report on it, compare it and build a dataset from it."""

    directory: Path
    config: RunConfig
    history: list[HistoryRow] = field(default_factory=list)
    front: list[FrontMember] = field(default_factory=list)
    evaluated: list[tuple[float, ...]] = field(default_factory=list)  # as told, in config's order
    # The safety measures of each evaluated candidate (empty: a run from before the limits).
    measured: list[tuple[float, ...]] = field(default_factory=list)

    @property
    def evaluations(self) -> int:
        return self.history[-1].evaluations if self.history else 0

    @property
    def wall_seconds(self) -> float:
        return self.history[-1].wall_seconds if self.history else 0.0

    @property
    def stopped(self) -> str | None:
        """Why the run stopped, or None if it has not: the termination's reason, from the
        history, which is how the run itself decided."""
        if not self.history:
            return None
        hypervolumes = [row.hypervolume for row in self.history]
        return self.config.termination.reason(hypervolumes, self.evaluations)


def read_run(directory: Path) -> RunRecord:
    """The run in `directory` as its files left it after its last generation (FileNotFoundError
    without a config.json; ValueError for a file of another format)."""
    directory = Path(directory)
    config = RunConfig.model_validate_json(read_bounded(directory / CONFIG_JSON, MAX_RECORD_BYTES))
    if not (directory / HISTORY_CSV).exists():  # stopped before its first generation ended
        return RunRecord(directory, config)
    return RunRecord(
        directory,
        config,
        read_history(directory / HISTORY_CSV),
        read_front_json(directory / FRONT_JSON),
        read_evaluated(directory / EVALUATED_CSV),
        read_measured(directory / EVALUATED_CSV),
    )


def results_csv(rows: Sequence[dict[str, object]]) -> bytes:
    """An experiment's results.csv: one row per run or per pair, columns in the rows' order."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue().encode()
