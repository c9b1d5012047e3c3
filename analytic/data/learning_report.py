"""The report of a learned model (analytic/data/learning.py's report.md): what the model is, and
its scores beside the anchors' and per joint, for an arm of any joints."""

import math
from collections.abc import Sequence
from typing import Any

from gainfarm.analytic.data.dataset_columns import JOINTS_BEFORE
from gainfarm.models.dynamics import DynamicsModel

# The joints a mean nMSE averages: every one but the last. The last (the iiwa 14's A7, the UR5e's
# wrist 3) turns only the flange: its torque varies by well under a N·m, so its nMSE measures
# noise and friction, not dynamics; the issue's convention leaves it out (nmse_mean_all keeps
# it). MEAN_JOINTS are the iiwa 14's, A1..A6.
MEAN_JOINTS = JOINTS_BEFORE[:-1]
# The one RMSE published for a learned model of a real iiwa 14, 0.14 N·m (Çallar and Böttger,
# RA-L 2022), is for the four heavy joints: the report puts the mean of A1-A4's RMSE beside it.
# Of any arm, `rmse_a1_a4` is the mean over its first four joints (the base's: the heaviest).
PUBLISHED_JOINTS = 4
PUBLISHED_ROBOT = "iiwa14"
PUBLISHED_RMSE = 0.14


def mean_joints(joints: Sequence[str]) -> tuple[str, ...]:
    """The joints a mean nMSE averages (MEAN_JOINTS' rule): all but the flange's."""
    return tuple(joints[:-1]) if len(joints) > 1 else tuple(joints)


def what(model: DynamicsModel) -> str:
    about = model.about
    if model.kind == "rigid":
        return "The rigid-body physics of the plant's arm (MuJoCo), no friction: not trained."
    if model.kind == "plant":
        return (
            "The simulated plant's own dynamics (its true arm, payload and friction): not "
            "trained, the anchor no learned model can beat; only noise separates it from the data."
        )
    if model.kind == "linear":
        flaws = about.get("inconsistencies", [])
        before = about.get("unconstrained_flaws", [])
        if flaws:
            consistency = (
                f"The identified parameters are **not physically consistent** ({len(flaws)} "
                f"flaws: {'; '.join(flaws[:3])}{'; ...' if len(flaws) > 3 else ''})."
            )
        elif before:
            consistency = (
                "The parameters are physically consistent by construction (every link's "
                "pseudo-inertia positive definite, friction and rotor inertia positive): plain "
                f"least squares left {len(before)} flaws ({'; '.join(before[:2])}; ...), and "
                "fitting over consistent arms only gave up "
                f"{100 * about.get('consistency_cost', 0.0):.3f} % of the torque variance it "
                "explained."
            )
        else:
            consistency = (
                "Plain least squares gave physically consistent parameters (every link's "
                "pseudo-inertia positive definite, friction and rotor inertia non-negative)."
            )
        return (
            f"Linear in {model.parameters.size} parameters (Pinocchio's regressor, rotor "  # type: ignore[union-attr]
            "inertia, viscous and "
            f"Coulomb-like friction per joint); {about['identified_rank']} directions identified "
            f"from the train split, the rest kept at the documented arm's values. {consistency}"
        )
    on = "the rigid physics' residual" if model.kind == "residual" else "the target"
    return (
        f"A {'×'.join(str(h) for h in about['hidden_layers'])} ReLU network on {on}, trained "
        f"{about['epochs_run']} epochs on the train split; epoch {about['best_epoch']} kept, "
        f"chosen on {about['chosen_on']}."
    )


def span(joints: Sequence[str]) -> str:
    """`joints` as a range of names: A1-A6."""
    return joints[0] if len(joints) == 1 else f"{joints[0]}-{joints[-1]}"


def anchors_table(scores: dict[str, Any], robot: str) -> list[str]:
    """The model beside the true model's floor and the rigid prior, on all and calm episodes."""
    unit = scores["unit"]
    first = span(tuple(scores["nmse"])[:PUBLISHED_JOINTS])
    rmse = f"RMSE {first} ({unit})"
    lines = [
        f"| model, test split | nMSE all | nMSE calm | {rmse} all | {rmse} calm |",
        "|---|---|---|---|---|",
    ]
    named = [
        (f"**{scores['kind']}** (this model)", scores),
        ("plant's own dynamics (the floor)", scores["floor"]),
        ("rigid prior (untrained)", scores["prior"]),
    ]
    for name, entry in named:
        calm = entry["calm"] or {}
        lines.append(
            f"| {name} | {entry['nmse_mean']:.4f} | {shown(calm.get('nmse_mean'), '.4f')} | "
            f"{entry['rmse_a1_a4']:.3g} | {shown(calm.get('rmse_a1_a4'), '.3g')} |"
        )
    floor = scores["floor"]["nmse_mean"]
    ratio = scores["nmse_mean"] / floor if floor > 0 else math.inf
    lines += [
        "",
        f"This model's nMSE is {ratio:.1f} times the floor's"
        + (
            f"; its RMSE over {first} is {scores['rmse_a1_a4']:.3g} {unit}, beside the "
            f"{PUBLISHED_RMSE} N·m published for a model learned on a real iiwa 14 (Çallar and "
            "Böttger, RA-L 2022): a simulated plant with its noise, not that robot."
            if scores["target"] == "inverse" and robot == PUBLISHED_ROBOT
            else "."
        ),
    ]
    return lines


def shown(value: float | None, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def scores_table(scores: dict[str, Any]) -> list[str]:
    unit = scores["unit"]
    calm = scores["calm"] or {}
    floor = scores["floor"]
    lines = [
        f"| joint | nMSE all | nMSE calm | floor's nMSE | RMSE all ({unit}) | RMSE calm ({unit}) "
        f"| variance (({unit})²) |",
        "|---|---|---|---|---|---|---|",
    ]
    joints = tuple(scores["nmse"])
    for joint in joints:
        lines.append(
            f"| {joint} | {scores['nmse'][joint]:.4f} | "
            f"{shown(calm.get('nmse', {}).get(joint), '.4f')} | {floor['nmse'][joint]:.4f} | "
            f"{scores['rmse'][joint]:.4g} | {shown(calm.get('rmse', {}).get(joint), '.4g')} | "
            f"{scores['variance'][joint]:.4g} |"
        )
    lines.append(
        f"| mean {span(mean_joints(joints))} | {scores['nmse_mean']:.4f} | "
        f"{shown(calm.get('nmse_mean'), '.4f')} | "
        f"{floor['nmse_mean']:.4f} | | | |"
    )
    return lines
