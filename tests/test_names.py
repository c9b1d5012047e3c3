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
