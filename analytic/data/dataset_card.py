"""The dataset's card, its README.md: what it holds, every column and its unit, where its logs
come from, how it was split and what was left out, and the command that made it."""

import textwrap
from collections.abc import Sequence

from gainfarm.analytic.data.arm import joint_range, title
from gainfarm.analytic.data.dataset_columns import (
    CALM_CHATTER,
    DATASET_VERSION,
    JOINT_SIGNALS,
    SG_ORDER,
    SG_WINDOW,
    TRAJECTORY_ID_DIGITS,
)
from gainfarm.analytic.data.dataset_runs import ChosenRun, Selection
from gainfarm.analytic.data.dataset_split import DEFAULT_SPLIT, Split
from gainfarm.cli.words import counted
from gainfarm.models import robot_of
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD


def _paragraph(text: str) -> str:
    """`text` wrapped as the card's other paragraphs are, at 96 columns."""
    return textwrap.fill(text, width=96, break_long_words=False, break_on_hyphens=False)


def interface_text(plant: PlantSpec) -> str:
    """What the card says of a run's torque interface: how its `u` became `u_motor`."""
    if plant.interface == "fri":
        return (
            f"behind {_interface_name(plant)} (the robot added its gravity model of the "
            f"{plant.inertials} inertials to `u`: `u_motor` is the sum)"
        )
    return "on a plain torque interface (`u_motor` is `u`)"


def _interface_name(plant: PlantSpec) -> str:
    """The torque interface that adds the robot's gravity model, by its maker's name."""
    if plant.robot == "iiwa14":  # the words of every card before other arms
        return "KUKA's FRI torque interface"
    return f"{robot_of(plant).torque_interface.name} (gravity added as FRI does)"


def card(
    counts: dict[str, int],
    chosen: Sequence[ChosenRun],
    selection: Selection,
    split: Split = DEFAULT_SPLIT,
    split_seed: int = 0,
) -> str:
    """The dataset's README.md: what it holds, every column and its unit, how it was made."""
    robot = chosen[0].plant.robot if chosen else "iiwa14"
    joints = robot_of(robot).joint_names
    suffixes = joint_range(joints)
    joint_columns = "\n".join(
        f"  - `{signal}_{suffixes}` ({unit}): {description}"
        for signal, (unit, description) in JOINT_SIGNALS.items()
    )
    chosen_text = (
        "every Pareto-front controller"
        if selection == "front"
        else "the knee (the front member `analytic export` takes: the least worse objective, both "
        "on a log scale between the front's ideal and nadir)"
    )
    runs = "\n".join(
        f"- `{run.name}`: run_id `{run.run_id}`, {interface_text(run.plant)}" for run in chosen
    )
    fractions = ",".join(f"{value:g}" for value in split)
    logs, rerun, caution = _logs_text(counts)
    limits = _left_out_text(counts)
    command = _command(counts, selection, fractions, split_seed)
    opening = _paragraph(
        f"Torque, position and velocity episodes of a simulated {title(robot)} "
        f"({len(joints)} joints; MuJoCo, "
        "elastic joints unless the `model` column says otherwise) under PD controllers tuned by "
        f"NSGA-II for tracking accuracy and torque smoothness: {chosen_text} of each run below, "
        f"on each trajectory it was tuned on{_rerun_line(counts)}."
    )
    summary = _paragraph(
        f"{counted(counts['episodes'], 'episode')}, {counts['ticks']:,} ticks at 500 Hz (control "
        f"period {CONTROL_PERIOD} s), {counted(counts['controllers'], 'controller')} from "
        f"{counted(counts['runs'], 'run')}, on "
        f"{counted(counts['trajectories'], 'trajectory')}. Dataset version "
        f"{DATASET_VERSION}.{limits}"
    )
    variant_text = _variant_text(counts)
    return f"""# gainfarm dynamics dataset

{opening}

{summary}

{runs}

## Split

By trajectory, never by tick: every tick of every episode of one `trajectory_id` is in the same
part, so a model is tested on motions it never saw. Fractions {fractions} (train, validation,
test) of the trajectories, ordered by the SHA-256 of `<split seed>:<trajectory_id>` (split seed
{split_seed}), each part with a positive fraction given at least one: {counts["train"]} train,
{counts["validation"]} validation, {counts["test"]} test trajectories.{variant_text}

## Files

- `ticks.parquet`: one row per 2 ms control tick. `episode_id`, `trajectory` (its kind),
  `trajectory_id`, `split`, `t` (s since the episode started), and per joint:
{joint_columns}

  and `ee_x..z`, `ee_des_x..z` (flange position and its desired value, m, base frame).
  Row `k` of an episode is tick `k` of its MCAP log: the state sensed at tick `k` and the command
  `u` then applied until tick `k + 1`. `qdd` is computed within each episode, `(qd[k+1] - qd[k]) /
  {CONTROL_PERIOD}`: the acceleration produced while row `k`'s `u` was applied, so it pairs with
  `u` exactly; it is NaN on each episode's last tick (never a difference across two episodes).
  `qdd_sg` is the acceleration at tick `k` from a Savitzky-Golay fit of `q` (order {SG_ORDER},
  {SG_WINDOW} ticks centred on `k`, within the episode): the difference's noise gives even the
  plant's own model a test nMSE near 0.09 on the realistic plant, this fit near 0.001. Learn and
  score on `qdd_sg`. Motor side (`theta`, `theta_d`) and torque sensors (`tau`) are as the sensors
  report them, noise included on the realistic plant; `u` is the controller's command as the robot
  took it (after the plant's delay and saturation), and `u_motor` the torque the motors exerted:
  behind KUKA's FRI torque interface, `u` plus the robot's own gravity model at the angles it
  measured (the fed-back side's `theta` or `q`), saturated; on a plain torque interface, `u`. A
  model of the arm's dynamics predicts `u_motor`. Each run above says its interface; the `model`
  column of `episodes.parquet` says which plant: interface, friction, delay, sensors, feedback
  side.
- `episodes.parquet`: one row per episode. `episode_id` (`<first 8 hex digits of the
  run_id>-<job id>`, with `-rerun-` for reruns), `run` (the run directory's name, or `rerun`),
  `run_id` (the controller's run, from its run.json), `source` (`tuning` or `rerun`),
  `trajectory_id`, `kp_{suffixes}` (N·m/rad), `kd_{suffixes}` (N·m·s/rad), `f_acc` (mean
  end-effector error, m), `f_t` (mean squared torque change per tick, (N·m)²), `diverged`, `ticks`,
  `trajectory`, `duration` (s), `trajectory_spec` and `model` (JSON), `gravity_compensation`,
  `feedforward` (the learned model's SHA-256, or empty),
  `candidate_f_acc`, `candidate_f_t` (the controller's objectives over its run's trajectory set),
  the safety measures `torque_step`, `saturated_fraction`, `speed`, `chatter`, `lag` (rad),
  `within_limits`, `calm` (ran to its end, chatter within {CALM_CHATTER:g}), `split`.
- `trajectories.parquet`: one row per distinct trajectory. `trajectory_id` (the first
  {TRAJECTORY_ID_DIGITS} hex digits of the SHA-256 of `spec`), `kind`, `seed`, `center_x..z` (m),
  `size` (m), `duration` (s), `twist` (rad), `turns`, `waypoints`, `harmonics`, `spec` (the
  TrajectorySpec as canonical JSON: sorted keys, no spaces), `split`, `episodes`.
- `episodes/<episode_id>.mcap`: the original logs (ROS 2 CDR: `/joint_states`,
  `/joint_commands`, `/motor_states`, `/joint_reference`, `/ee/actual`, `/ee/desired`, and in
  recent logs, for ROS 2 tools such as Foxglove, `/tf` and `/robot_description`: the arm's links
  at 50 Hz and its URDF; the channel contract is in gainfarm's schemas/README.md), each with its
  full spec in the `gainfarm.episode` metadata record. They are {logs}.{rerun}{caution}

Every Parquet column carries its unit (`unit`: rad, rad/s, rad/s^2, N*m, m, s, or empty for ids
and counts) and a `description` in its field metadata; each table's schema metadata holds the
`control_period` (s), the `dataset_version`, the `split` and the `split_seed`, the `robot`
(`{robot}`) and its `joint_names` (JSON).

Made with:

    {command}
"""


def _logs_text(counts: dict[str, int]) -> tuple[str, str, str]:
    """What the card says of the logs: where they are from, the rerun's, and a caution."""
    if counts["linked"] + counts["copied"] == 0:
        logs = "the rerun's own, none a tuning run's"
    elif counts["copied"] == 0:
        logs = "hard links to the runs' own logs (the same inode, no second copy)"
    elif counts["linked"] == 0:
        logs = "copies of the runs' logs (the file system refused hard links)"
    else:
        logs = (
            f"{counts['linked']} hard links to the runs' own logs and {counts['copied']} copies "
            "(where the file system refused a link)"
        )
    rerun = (
        f" The {counts['rerun']} rerun episodes' logs were written for this dataset."
        if counts["rerun"]
        else ""
    )
    caution = " Do not edit a log in place: a hard-linked one changes in its run too." * bool(
        counts["linked"]
    )
    return logs, rerun, caution


def _rerun_line(counts: dict[str, int]) -> str:
    """The opening's words on the rerun, if there was one."""
    variants = counts.get("rerun_plants", 0)
    return (
        f", and each of them run once more on the {counts['rerun_trajectories']} trajectories of "
        "the rerun (`source` rerun)"
        + (
            f", on its run's plant and on {variants} variants of it drawn from the plant's "
            "uncertainty ranges (models/uncertainty.toml; the `model` column says which)"
            if variants
            else ""
        )
        if counts["rerun"]
        else ""
    )


def _left_out_text(counts: dict[str, int]) -> str:
    """The summary's words on the episodes left out, or kept though rough."""
    left_out = counts.get("infeasible_left_out", 0)
    limits = (
        f" {left_out} episodes of controllers that break their run's safety limits were left "
        "out (`analytic dataset --infeasible` keeps them)."
        if left_out
        else ""
    )
    rough_out = counts.get("rough_left_out", 0)
    if rough_out:
        limits += (
            f" {rough_out} episodes that chatter or diverged were left out (`--include-rough` "
            "keeps them)."
        )
    elif counts.get("rough", 0):
        limits += (
            f" {counts['rough']} episodes chatter or diverged, kept by `--include-rough`: their "
            "`calm` is false; score a model on the calm ones."
        )
    return limits


def _command(counts: dict[str, int], selection: Selection, fractions: str, split_seed: int) -> str:
    """The command that made the dataset, as far as the card can tell it."""
    variants = counts.get("rerun_plants", 0)
    command = f"analytic dataset ... --select {selection} --split {fractions}"
    command += f" --split-seed {split_seed}" + (" --rerun FILE" if counts["rerun"] else "")
    command += f" --plants {variants}" * bool(variants)
    command += " --include-rough" * bool(counts.get("rough", 0))
    return command


def _variant_text(counts: dict[str, int]) -> str:
    """The split's words on the episodes on other plants than their run's, if any."""
    on_variants = counts.get("on_variants", 0)
    return (
        "\n\n"
        + _paragraph(
            f"One plant per part: the {on_variants} episodes on a plant other than their run's "
            "own (a robust run's tuning variants, the rerun's `--plants`) are in "
            "`train_variants`, `validation_variants` and `test_variants`, by the same "
            "trajectories. `train`, `validation` and `test` hold the runs' own plants: the same "
            "motion asks for other torques on another plant, a spread no model without the "
            "plant among its inputs can learn. Train on the variants too to learn across plants; "
            "`test_variants` measures what a model of one plant misses on the others."
        )
        if on_variants
        else ""
    )
