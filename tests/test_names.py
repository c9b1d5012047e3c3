"""One meaning per word (docs/architecture.md's glossary), where the source can tell: no two
classes of the project share a name, and no option means two things on two commands."""

import ast
from collections import defaultdict
from pathlib import Path

import click

from gainfarm.analytic.cli import app as analytic_app
from gainfarm.broker.cli import app as broker_app
from gainfarm.worker.cli import app as worker_app

ROOT = Path(__file__).parents[1]
SOURCES = ("analytic", "worker", "broker", "schemas", "models", "gainfarm", "bench", "docker")


def test_no_two_classes_share_a_name() -> None:
    where = defaultdict(list)
    for folder in SOURCES:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ClassDef):
                    where[node.name].append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert {name: places for name, places in where.items() if len(places) > 1} == {}


def _commands(group: click.Group, prefix: str) -> dict[str, click.Command]:
    found = {}
    context = click.Context(group)
    for name in group.list_commands(context):
        command = group.get_command(context, name)
        assert command is not None, name
        if isinstance(command, click.Group):
            found |= _commands(command, f"{prefix} {name}")
        else:
            found[f"{prefix} {name}"] = command
    return found


def test_the_arm_s_joints_and_a_learned_model_s_kind_have_their_own_options() -> None:
    commands = (
        _commands(analytic_app, "analytic")
        | _commands(worker_app, "worker")
        | _commands(broker_app, "broker")
    )
    options = {
        name: {opt for param in command.params for opt in getattr(param, "opts", ())}
        for name, command in commands.items()
    }
    assert not any("--model" in opts for opts in options.values())  # it meant both, once
    for name in ("analytic start", "analytic batch", "worker episode"):
        assert "--joints" in options[name] and "--kind" not in options[name], name
    assert "--kind" in options["analytic learn"] and "--joints" not in options["analytic learn"]


def _trees() -> list[tuple[Path, ast.Module]]:
    return [
        (path, ast.parse(path.read_text(), str(path)))
        for folder in SOURCES
        for path in sorted((ROOT / folder).rglob("*.py"))
    ]


# Files whose keys are a format read outside gainfarm, kept as they were: the exported controller
# (a robot-side loader reads its `model`, beside `plant`, the plant's name).
FORMATS_KEPT = {"schemas/controller.py"}


def test_a_field_holding_the_plant_is_named_plant() -> None:
    """`model` meant the plant beside learned models and MuJoCo's MjModel: a field or parameter
    annotated with the plant's spec is the plant (`plants` for many)."""
    wrong = []
    for path, tree in _trees():
        if path.relative_to(ROOT).as_posix() in FORMATS_KEPT:
            continue
        for node in ast.walk(tree):
            named = None
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                named = (node.target.id, node.annotation)
            elif isinstance(node, ast.arg) and node.annotation is not None:
                named = (node.arg, node.annotation)
            if named and ast.unparse(named[1]).strip("'\"") == "PlantSpec" and "model" in named[0]:
                wrong.append(f"{path.relative_to(ROOT)}:{node.lineno} {named[0]}")
    assert wrong == []


def test_no_name_says_evaluation_for_an_episode_s_result() -> None:
    """An evaluation scores a candidate (its episodes combined); one job's outcome is an episode
    result. No variable, parameter or attribute is named `evaluation`: in this code it only ever
    held an EpisodeResult."""
    found = [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for path, tree in _trees()
        for node in ast.walk(tree)
        if (isinstance(node, ast.Name) and node.id == "evaluation")
        or (isinstance(node, ast.arg) and node.arg == "evaluation")
        or (isinstance(node, ast.Attribute) and node.attr == "evaluation")
    ]
    assert found == []


def test_experiments_state_findings_the_broker_gives_verdicts() -> None:
    found = [
        f"{path.relative_to(ROOT)}:{node.lineno} {name}"
        for path, tree in _trees()
        if "experiments" in path.parts
        for node in ast.walk(tree)
        for name in _names_defined(node)
        if "verdict" in name.lower()
    ]
    assert found == []


def _names_defined(node: ast.AST) -> list[str]:
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
        return [node.name]
    if isinstance(node, ast.arg):
        return [node.arg]
    if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
        return [node.id]
    if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
        return [node.target.id]
    if isinstance(node, ast.keyword) and node.arg:
        return [node.arg]
    if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.isidentifier():
        return [node.value]  # a dict key or a column named so
    return []
