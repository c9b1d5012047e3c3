"""What a user's main job costs: `analytic start --pop 30` on its local farm, to a fixed budget,
against the same episodes run by a plain multiprocessing.Pool over every core, and against
Optuna's own parallel loop with the same evaluation. All measured in one run of this script.

    python bench/main_job.py [--evaluations 600] [--pop 30] [--workers N] [--plants 8]
                             [--baseline-python PATH] [--quick]
    python bench/main_job.py --arms iiwa14,ur5e,panda,gen3 [--evaluations E] [--workers N]

Three cases, each a process tree started from here and measured whole (wall time from its start
to its end, start-up included; CPU time of every process in it, from getrusage(RUSAGE_CHILDREN)
once each has been waited for):

- run: `python -m gainfarm.analytic start --local --pop P --evaluations E` as a subprocess, with
  the CLI's default `--workers` unless --workers is given: the broker, the workers, the tuning
  loop, the records, the front's validation and the report, as a user gets them.
- pool: multiprocessing.Pool(cores) running the run's own candidates (read back from its
  checkpoint, in the order told) with gainfarm.worker.job.simulate, the worker's whole job
  (episode, MCAP log, scores), each candidate's objectives as the run computes them.
- optuna: `study.optimize(objective, n_trials=E, n_jobs=cores)` with NSGAIISampler(pop P) over
  the run's search space (log10 of each gain, analytic.tuning.search_space), the objective being
  the pool's evaluation. Optuna's n_jobs are threads in one process.

- robust run: the same `analytic start` with `--plants K` (each candidate also on K plant
  variants: K + 1 episodes an evaluation), at the same evaluations.

With --arms NAME,NAME...: the advice instead, per arm. The README's main job (`analytic start
--pop 30`: robust, to convergence, its advice checked on 64 held-out plants) with `--robot NAME`
for each arm, one after the other; printed, one table: per arm, the controller the check
recommends (or the default gains, if none held) and its held-out median and worst f_acc against
the arm's default gains', whether both are at most theirs (issue 49's target: every arm), and
whether the arm's torque interface adds gravity compensation (PD + gravity compensation, as the
iiwa's FRI does) or the PD is all.

The anchor: one episode's physics stepped in one C call: the default gains' episode on the run's
first path and plant, its recorded motor torques and friction replayed through MuJoCo's
`rollout` from its first state (bench/episode_bench.py's anchor, checked to retrace the
episode), the fastest of five, in CPU time. Not `mj_step(nstep)` with constant torques: an arm
held open loop drifts into its joint limits and pays their constraints, some 45 % more physics
than the episode's (31.3 against 21.5 ms, measured once), which would flatter every ratio.

Printed: each case's wall time, CPU per evaluation and evaluations/s; the run's throughput over
the pool's (target >= 1.3x); the run's CPU per evaluation over its episodes' physics (target <=
1.4x); the robust run's wall time over the run's (target <= 3.5x). With --baseline-python PATH,
the same run again with that interpreter (whose `analytic` is an older checkout, e.g. the
previous main), back to back, and the wall-time ratio now/then (target <= 0.5x). The machine's
other load moves every figure: compare the ratios of one run, not figures of different runs.
"""

import csv
import importlib.util
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
from common import SPAWN, print_table
from episode_bench import physics

from gainfarm import plugins
from gainfarm.analytic.tuning.check import read_check
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.models import robot_of
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.objectives import objectives
from gainfarm.worker.job import simulate

CORES = os.cpu_count() or 1
RUN_TARGET = 1.3  # the run's throughput over the pool's, at least
PHYSICS_TARGET = 1.4  # the run's CPU per evaluation over its episodes' physics, at most
ROBUST_TARGET = 3.5  # the robust run's wall time over the nominal run's, at most
BASELINE_TARGET = 0.5  # the run's wall time over the previous main's, at most


@dataclass
class Case:
    name: str
    evaluations: int
    wall_s: float
    cpu_s: float

    @property
    def per_s(self) -> float:
        return self.evaluations / self.wall_s

    @property
    def cpu_ms(self) -> float:
        return 1000 * self.cpu_s / self.evaluations


def children_cpu() -> float:
    """User + system CPU seconds of every child (and theirs) waited for so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def measured(name: str, evaluations: Callable[[], int], run: Callable[[], None]) -> Case:
    """Run `run` (which starts and waits for a process tree) and measure it."""
    cpu, started = children_cpu(), time.perf_counter()
    run()
    wall = time.perf_counter() - started
    return Case(name, evaluations(), wall, children_cpu() - cpu)


# --- the run -----------------------------------------------------------------------------------


def analytic_command(python: str) -> list[str]:
    """How `python` starts the analytic CLI: `gainfarm.analytic` now, `analytic` before the
    one import name (the previous main's layout)."""
    try:
        found = subprocess.run(
            [python, "-c", "import importlib.util as u; print(bool(u.find_spec('gainfarm')))"],
            capture_output=True,
            text=True,
            check=True,
        )
    except (OSError, subprocess.CalledProcessError):
        raise click.ClickException(f"--baseline-python: {python} does not run Python") from None
    return [python, "-m", "gainfarm.analytic" if found.stdout.strip() == "True" else "analytic"]


def run_case(name: str, analytic: list[str], options: Sequence[str], out: Path) -> Case:
    """`analytic start` with `options` into `out`, measured whole."""
    command = [*analytic, "start", "--local", *options, "--out", str(out)]
    transcript = out.parent / f"{out.name}.log"

    def run() -> None:
        with transcript.open("wb") as sink:
            done = subprocess.run(  # not from a checkout: `-m analytic` must be the install's
                command,
                stdin=subprocess.DEVNULL,
                stdout=sink,
                stderr=subprocess.STDOUT,
                cwd=out.parent,
            )
        if done.returncode != 0:
            tail = transcript.read_text(errors="replace").strip().splitlines()[-15:]
            raise click.ClickException(
                f"{' '.join(command)} exited with {done.returncode}:\n" + "\n".join(tail)
            )

    return measured(name, lambda: evaluations_done(out), run)


def evaluations_done(out: Path) -> int:
    """The evaluations the run in `out` recorded (history.csv's last row: every version has it)."""
    with (out / "history.csv").open() as stream:
        return int(list(csv.DictReader(stream))[-1]["evaluations"])


def candidates(out: Path) -> tuple[RunConfig, list[PDGains]]:
    """The run's config and every candidate it evaluated, in the order told."""
    with TuningRun.open(out) as run:
        return run.config, list(run.state.provenance)


def physics_seconds(config: RunConfig, repeats: int = 5) -> float:
    """CPU s of one episode's physics in one C call (the module's docstring), the fastest of
    `repeats`."""
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=config.trajectories[0], plant=config.plant)
    replay = physics(spec)  # checked to retrace the episode
    fastest = float("inf")
    for _ in range(repeats):
        began = time.process_time()
        replay()
        fastest = min(fastest, time.process_time() - began)
    return fastest


def episodes_per_evaluation(config: RunConfig) -> int:
    """A candidate's episodes: each path on the nominal plant and on each variant."""
    return len(config.trajectories) * (1 + len(config.plants))


# --- the same evaluation, without the farm -----------------------------------------------------


def evaluate(config: RunConfig, gains: PDGains) -> tuple[float, float]:
    """A candidate's objectives as a run computes them: each of its episodes run by the worker's
    whole job (episode, log, scores), the objectives over its trajectories."""
    scores = []
    for trajectory in config.trajectories:
        spec = EpisodeSpec(
            gains=gains,
            trajectory=trajectory,
            plant=config.plant,
            feedforward=config.feedforward,
            objectives=config.objectives,
        )
        scores.append(simulate(spec).scores)
    return objectives(scores, config.objective_weights)


def _evaluate_json(config_json: str, gains: PDGains) -> tuple[float, float]:
    return evaluate(RunConfig.model_validate_json(config_json), gains)


def pool_tree(config_json: str, gains: list[PDGains], cores: int, done: Any) -> None:
    """A process: `gains` evaluated by a Pool of `cores` processes (joined, so their CPU is this
    process's children's)."""
    pool = SPAWN.Pool(cores)
    points = pool.starmap(_evaluate_json, [(config_json, g) for g in gains], chunksize=1)
    pool.close()
    pool.join()
    done.value = len(points)


def optuna_tree(config_json: str, budget: int, pop: int, seed: int, cores: int, done: Any) -> None:
    """A process: Optuna's NSGA-II over the run's search space, `budget` trials on `cores`
    threads, each trial the pool's evaluation."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    config = RunConfig.model_validate_json(config_json)
    space = SearchSpace()
    bounds = list(zip(space.lower, space.upper, strict=True))

    def objective(trial: "optuna.Trial") -> tuple[float, float]:
        x = [trial.suggest_float(f"x{i}", low, high) for i, (low, high) in enumerate(bounds)]
        return evaluate(config, space.gains(x))

    study = optuna.create_study(
        directions=["minimize", "minimize"],
        sampler=optuna.samplers.NSGAIISampler(population_size=pop, seed=seed),
    )
    study.optimize(objective, n_trials=budget, n_jobs=cores)
    done.value = len(study.trials)


def tree_case(name: str, target: Callable[..., None], *args: object) -> Case:
    """`target(*args, done)` in a spawned process, measured whole; `done` is how many
    evaluations it made."""
    done = SPAWN.Value("i", 0)

    def run() -> None:
        process = SPAWN.Process(target=target, args=(*args, done))
        process.start()
        process.join()
        if process.exitcode != 0:
            raise click.ClickException(f"the {name} case exited with {process.exitcode}")

    return measured(name, lambda: done.value, run)


# --- the advice on every arm --------------------------------------------------------------------


@dataclass(frozen=True)
class Advised:
    """One arm's main job: what its check advised and how it and the default gains fared held
    out (m)."""

    arm: str
    joints: int
    gravity: bool  # the arm's torque interface adds gravity compensation to the PD
    case: Case
    advice: str  # "row N" of front.csv, or "default gains" (no member held)
    plants: int
    median: float
    worst: float
    default_median: float
    default_worst: float

    @property
    def holds(self) -> bool:
        return self.median <= self.default_median and self.worst <= self.default_worst


def advised(arm: str, case: Case, out: Path) -> Advised:
    """What the check of the run in `out` (an `analytic start --robot arm`) advised."""
    record = read_check(out)
    if record is None:
        raise click.ClickException(f"{arm}: the run in {out} has no held-out check")
    by_name = {item["name"]: item for item in record["controllers"]}
    default = by_name["default gains"]
    chosen = by_name.get("recommended", default)
    robot = robot_of(arm)
    return Advised(
        arm=arm,
        joints=len(robot.joint_names),
        gravity=robot.torque_interface.adds_gravity,
        case=case,
        advice="default gains" if chosen is default else f"row {chosen['row']}",
        plants=record["plants"],
        median=chosen["median_f_acc"],
        worst=chosen["worst_f_acc"],
        default_median=default["median_f_acc"],
        default_worst=default["worst_f_acc"],
    )


def arms_advice(arms: Sequence[str], options: Sequence[str]) -> list[Advised]:
    """The main job (`analytic start --robot ARM` with `options`) on each of `arms`."""
    found = []
    out = Path(tempfile.mkdtemp(prefix="gainfarm-main-job-arms-"))
    try:
        for arm in arms:
            print(f"analytic start --robot {arm} {' '.join(options)} ...", file=sys.stderr)
            command = analytic_command(sys.executable)
            case = run_case(arm, command, ["--robot", arm, *options], out / arm)
            found.append(advised(arm, case, out / arm))
            print(f"  {found[-1]}", file=sys.stderr, flush=True)  # each as it comes
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return found


def print_advice(found: Sequence[Advised], options: Sequence[str]) -> None:
    mm = lambda metres: f"{1000 * metres:.2f}"  # noqa: E731
    print(f"analytic start --robot ARM {' '.join(options)} (the README's main job), one run")
    print_table(
        (
            "arm",
            "joints",
            "PD +",
            "evaluations",
            "wall s",
            "advice",
            "held out",
            "median mm",
            "default median mm",
            "worst mm",
            "default worst mm",
            "at most the defaults'",
        ),
        "lrlrrlrrrrrl",
        (
            (
                a.arm,
                str(a.joints),
                "gravity compensation" if a.gravity else "nothing",
                str(a.case.evaluations),
                f"{a.case.wall_s:.0f}",
                a.advice,
                str(a.plants),
                mm(a.median),
                mm(a.default_median),
                mm(a.worst),
                mm(a.default_worst),
                "yes" if a.holds else "NO",
            )
            for a in found
        ),
    )
    held = sum(a.holds for a in found)
    said = "the advice's held-out median and worst at most the default gains'"
    print(f"{said}: {held} of {len(found)} arms")


# --- the command -------------------------------------------------------------------------------


@click.command(help=__doc__.split("\n\n")[0])
@click.option(
    "--evaluations",
    type=click.IntRange(min=1),
    help="the budget of every case  [default: 600; --quick: 60]",
)
@click.option("--pop", type=click.IntRange(min=4), help="population  [default: 30; --quick: 10]")
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    help="the run's local worker processes  [default: the CLI's]",
)
@click.option(
    "--baseline-python",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="also time the same run with this interpreter (its `analytic` an older checkout)",
)
@click.option(
    "--plants",
    type=click.IntRange(min=0),
    default=8,
    show_default=True,
    metavar="K",
    help="also the run with --plants K, at the same evaluations (0: not)",
)
@click.option("--quick", is_flag=True, help="a CI-sized run: 60 evaluations, population 10")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True)
@click.option(
    "--arms",
    metavar="NAME,NAME...",
    help="instead: the README's main job with --robot NAME for each arm, and its advice held out "
    "against the default gains' (--evaluations: a budget, not convergence)",
)
def main(
    evaluations: int | None,
    pop: int | None,
    workers: int | None,
    baseline_python: Path | None,
    plants: int,
    quick: bool,
    seed: int,
    arms: str | None,
) -> None:
    if arms is not None:
        names = [name.strip() for name in arms.split(",") if name.strip()]
        for name in names:
            try:
                plugins.check_name(plugins.ROBOTS, name)
            except plugins.PluginError as error:
                raise click.BadParameter(str(error), param_hint="'--arms'") from None
        options = ["--pop", str(pop or 30), "--seed", str(seed)]
        options += ["--evaluations", str(evaluations)] if evaluations else []
        options += ["--workers", str(workers)] if workers else []
        print_advice(arms_advice(names, options), options)
        return
    if importlib.util.find_spec("optuna") is None:
        raise click.ClickException("Optuna is needed: pip install -e '.[bench]'")
    budget = evaluations or (60 if quick else 600)
    pop = pop or (10 if quick else 30)
    # The nominal problem on the paper's f_t, as the previous main's default ran it (since issue
    # 46 the first command is robust on f_t_joint): the pool and Optuna run one episode a
    # candidate; --plants K is the robust case.
    options = [
        "--pop",
        str(pop),
        "--evaluations",
        str(budget),
        "--seed",
        str(seed),
        "--plants",
        "0",
    ]
    ours = ["--torque-measure", "raw"]  # an option the previous main has not
    if workers is not None:
        options += ["--workers", str(workers)]
    then = analytic_command(str(baseline_python)) if baseline_python is not None else None
    out = Path(tempfile.mkdtemp(prefix="gainfarm-main-job-"))
    try:
        say = lambda text: print(text, file=sys.stderr, flush=True)  # noqa: E731
        say(f"analytic start {' '.join(options)} on {CORES} cores ...")
        run = run_case("run", analytic_command(sys.executable), [*options, *ours], out / "run")
        config, told = candidates(out / "run")
        config_json = config.model_dump_json()
        say(f"pool of {CORES} on the run's {len(told)} candidates ...")
        pool = tree_case("pool", pool_tree, config_json, told, CORES)
        say(f"optuna, {budget} trials on {CORES} threads ...")
        study = tree_case("optuna", optuna_tree, config_json, budget, pop, seed, CORES)
        physics = physics_seconds(config) * episodes_per_evaluation(config)
        cases = [run, pool, study]
        if plants:
            say(f"the same run with --plants {plants} ...")
            robust = ["--plants", str(plants)]
            cases.append(
                run_case(
                    "robust run",
                    analytic_command(sys.executable),
                    [*options, *ours, *robust],
                    out / "robust",
                )
            )
        if then is not None:
            say(f"the same run with {baseline_python} ...")
            cases.append(run_case("baseline run", then, options, out / "then"))
    finally:
        shutil.rmtree(out, ignore_errors=True)
    farm = "" if workers is not None else " (the CLI's default --workers)"
    print(f"analytic start {' '.join(options)}{farm}; Pool({CORES}); Optuna n_jobs={CORES}")
    print_table(
        ("case", "evaluations", "wall s", "CPU ms/evaluation", "evaluations/s"),
        "lrrrr",
        (
            (c.name, str(c.evaluations), f"{c.wall_s:.1f}", f"{c.cpu_ms:.1f}", f"{c.per_s:.2f}")
            for c in cases
        ),
    )
    print(
        f"run/pool throughput: {run.per_s / pool.per_s:.2f}x (target >= {RUN_TARGET}x); "
        f"CPU per evaluation: {run.cpu_ms / pool.cpu_ms:.2f}x the pool's"
    )
    print(
        f"optuna/pool throughput: {study.per_s / pool.per_s:.2f}x; "
        f"CPU per evaluation: {study.cpu_ms / pool.cpu_ms:.2f}x the pool's"
    )
    print(
        f"run CPU per evaluation / its episodes' physics (replayed in one C call): "
        f"{run.cpu_s / run.evaluations / physics:.2f}x (target <= {PHYSICS_TARGET}x; "
        f"{1000 * physics:.1f} ms of physics an evaluation)"
    )
    if plants:
        robust_case = cases[3]
        print(
            f"robust/nominal wall time (--plants {plants}, same evaluations): "
            f"{robust_case.wall_s / run.wall_s:.2f}x (target <= {ROBUST_TARGET}x)"
        )
    if baseline_python is not None:
        then = cases[-1]
        print(
            f"run/baseline wall time: {run.wall_s / then.wall_s:.2f}x "
            f"(target <= {BASELINE_TARGET}x; {baseline_python})"
        )


if __name__ == "__main__":
    main()
