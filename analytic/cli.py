"""`analytic`: the analytic layer. Tune gains with NSGA-II on the farm (`start`, `resume`), take a
run's controller out of it (`export`), score an episode log (`evaluate`), evaluate fixed
candidates on the farm (`batch`), gather tuned controllers' episodes into a dataset (`dataset`),
learn the arm's dynamics from it (`learn`), run the paper's experiments (`experiment`), and watch
an episode as a video (`replay`)."""

from gainfarm.cli.app import program_group, run_app

# Each command's module (analytic/commands/) and the summary `analytic --help` lists: the help
# imports none of them, and a command line imports only its command's.
COMMANDS = {
    name: (f"gainfarm.analytic.commands.{name}:{name}", summary)
    for name, summary in {
        "batch": "Evaluate given gains on the farm; keep every episode.",
        "calibrate": "Fit a twin of an arm to its logged episodes.",
        "dashboard": "Watch runs and their farm live, in a web page.",
        "dataset": "Gather tuned controllers' episodes into a dataset.",
        "evaluate": "Score an episode from its MCAP log alone.",
        "excite": "Write safe excitation references to record on a real arm.",
        "experiment": "Rerun the paper's experiments, or compare optimisers.",
        "export": "Write a run's controller to use (the recommended one).",
        "learn": "Learn the arm's dynamics from a dataset.",
        "replay": "Render an episode log as a video.",
        "resume": "Continue a stopped run from its last checkpoint.",
        "start": "Tune the 14 PD gains on the farm (NSGA-II by default).",
        "validate": "Replay an arm's logged episodes on a twin: the gap.",
    }.items()
}


@program_group(__doc__, COMMANDS)
def app() -> None:
    pass


def main() -> None:
    run_app(app, "analytic")
