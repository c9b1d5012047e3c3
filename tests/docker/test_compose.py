"""docker/: the image and the compose file, checked without a Docker engine.

Every command they run is parsed by the real click commands (nothing is run), so a renamed option
or subcommand breaks these tests rather than a deployment.
"""

import importlib.util
import itertools
import json
import re
import shlex
import tomllib
from collections.abc import Iterator, Mapping
from functools import cache
from pathlib import Path, PurePosixPath
from types import ModuleType

import click
import pytest
import yaml

from gainfarm.analytic import cli as analytic_cli
from gainfarm.analytic.evaluators.local import STOP_SECONDS
from gainfarm.broker import cli as broker_cli
from gainfarm.worker import cli as worker_cli

ROOT = Path(__file__).resolve().parents[2]
DOCKER = ROOT / "docker"
COMPOSE_FILE = DOCKER / "compose.yaml"
SECURE_FILE = DOCKER / "compose.secure.yaml"
DOCKERFILE = DOCKER / "Dockerfile"
README = DOCKER / "README.md"
E2E_SCRIPT = DOCKER / "e2e.py"
PROGRAMS: dict[str, click.Group] = {
    "broker": broker_cli.app,
    "worker": worker_cli.app,
    "analytic": analytic_cli.app,
}
FARM_PORT = 7447


# --- reading the files -------------------------------------------------------------------------


@cache
def compose() -> dict:
    return yaml.safe_load(COMPOSE_FILE.read_text())


def service(name: str) -> dict:
    return compose()["services"][name]


@cache
def secure_overrides() -> dict:
    return yaml.safe_load(SECURE_FILE.read_text())


def secure_service(name: str) -> dict:
    """A service as `-f compose.yaml -f compose.secure.yaml` gives it: Compose's merge rules for
    the keys used here (scalars and health-check keys replaced, mappings merged, lists added)."""
    merged = dict(compose()["services"].get(name, {}))
    for key, value in secure_overrides()["services"][name].items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = {**merged[key], **value}
        elif isinstance(value, list) and key in ("volumes", "ports") and key in merged:
            merged[key] = [*merged[key], *value]
        else:
            merged[key] = value
    return merged


def interpolate(text: str, env: Mapping[str, str] | None = None) -> str:
    """Compose's `${VAR:-default}` with the variables of `env` set (none by default): every
    variable needs a default."""

    def value(match: re.Match[str]) -> str:
        assert match["default"] is not None, f"{match[0]} has no default in {COMPOSE_FILE.name}"
        return (env or {}).get(match["name"]) or match["default"]

    text = re.sub(r"\$\{(?P<name>\w+)(?::?-(?P<default>[^}]*))?\}", value, text)
    assert not re.search(r"(?<!\$)\$(?!\$)", text), f"uninterpolated $ in {text!r}"
    return text.replace("$$", "$")


def argv(command: str | list[str], env: Mapping[str, str] | None = None) -> list[str]:
    """A compose `command`/`test` as the argument vector the container gets: a string is split
    as a shell would, after interpolation (so a variable may hold several arguments)."""
    if isinstance(command, str):
        return shlex.split(interpolate(command, env))
    return [interpolate(str(part), env) for part in command]


def healthcheck_argv(check: dict) -> list[str]:
    kind, *rest = check["test"]
    assert kind in ("CMD", "CMD-SHELL"), check["test"]
    return rest if kind == "CMD" else shlex.split(rest[0])


def dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    lines = [line.strip() for line in text.splitlines()]
    return [
        (line.split(None, 1)[0].upper(), line.split(None, 1)[1] if " " in line else "")
        for line in lines
        if line and not line.startswith("#")
    ]


def instruction(name: str) -> list[str]:
    return [arguments for kind, arguments in dockerfile_instructions() if kind == name]


def dockerfile_args() -> dict[str, str]:
    """Each ARG and its default ("" without one)."""
    found = {}
    for arguments in instruction("ARG"):
        name, _, default = arguments.partition("=")
        found[name] = shlex.split(default)[0] if default.strip() not in ("", '""') else ""
    return found


def substitute(text: str, values: Mapping[str, str]) -> str:
    """The Dockerfile's `${NAME}` and `$NAME` with these values."""
    return re.sub(r"\$\{?(\w+)\}?", lambda match: values[match[1]], text)


def pip_install() -> tuple[list[str], list[str]]:
    """The one RUN that installs the project: its --mount options and the pip command."""
    (run,) = [arguments for arguments in instruction("RUN") if "pip install" in arguments]
    words = run.split()
    mounts = [word.removeprefix("--mount=") for word in words if word.startswith("--mount=")]
    command = [word for word in words if not word.startswith("--mount=")]
    return mounts, command


@cache
def load_e2e() -> ModuleType:
    """docker/e2e.py, which is not in a package: its choices, for the checks below."""
    spec = importlib.util.spec_from_file_location("docker_e2e", E2E_SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def dockerfile_cmd() -> list[str]:
    (cmd,) = instruction("CMD")
    assert cmd.startswith("["), "CMD in exec form, so the CLI is PID 1 and gets SIGTERM"
    return json.loads(cmd)


def readme_commands() -> Iterator[list[str]]:
    """Each command line of the README's bash blocks as tokens, comments dropped."""
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S):
        for line in re.sub(r"\\\n", " ", block).splitlines():
            if tokens := shlex.split(line, comments=True):
                yield tokens


def segments(tokens: list[str]) -> Iterator[list[str]]:
    """A shell line split at pipes and command separators."""
    current: list[str] = []
    for token in tokens:
        if token in ("|", "||", "&&", ";"):
            yield current
            current = []
        else:
            current.append(token.rstrip(";"))
    yield current


# --- the CLI check -----------------------------------------------------------------------------


def parse_invocation(args: list[str]) -> tuple[str, dict]:
    """Parse `PROGRAM SUBCOMMAND ...` with the real click commands; (subcommand, its params).

    click.UsageError (unknown subcommand or option, bad value, missing argument) if it is not
    a valid invocation. Nothing is invoked.
    """
    program, *rest = args
    assert program in PROGRAMS, f"{program!r} is not a gainfarm command"
    group = PROGRAMS[program]
    # The groups' one option is --version, which exits: in any invocation that runs something,
    # the subcommand comes first.
    assert [param.name for param in group.params] == ["version"]
    with group.make_context(program, list(rest)) as context:
        name, command, remaining = group.resolve_command(context, list(rest))
        assert name is not None and command is not None
        with command.make_context(name, remaining, parent=context) as sub:
            return name, sub.params


def gainfarm_invocations() -> list[tuple[str, list[str]]]:
    """Every gainfarm command the compose file and the Dockerfile run, with where it is."""
    found = [("Dockerfile CMD", dockerfile_cmd())]
    for prefix, services in (("", compose()), ("secure ", secure_overrides())):
        for name, spec in services["services"].items():
            if "command" in spec:
                found.append((f"{prefix}{name}.command", argv(spec["command"])))
            if "test" in spec.get("healthcheck", {}):
                found.append((f"{prefix}{name}.healthcheck", healthcheck_argv(spec["healthcheck"])))
    return found


def endpoint(value: str, protocol: str = "tcp") -> tuple[str, int]:
    match = re.fullmatch(rf"{protocol}/(?P<host>[^:/]+):(?P<port>\d+)", value)
    assert match, f"{value!r} is not a {protocol}/HOST:PORT endpoint"
    return match["host"], int(match["port"])


def container_port(mapping: str | int | dict) -> int:
    """The container side of a `ports` entry: 7447, "7447:7447", "127.0.0.1:7447:7447/tcp"."""
    if isinstance(mapping, dict):
        return int(mapping["target"])
    return int(str(mapping).rsplit(":", 1)[-1].split("/")[0])


def seconds(duration: str | int) -> float:
    """A compose duration such as 30s, 1m30s or 90."""
    if isinstance(duration, int):
        return float(duration)
    parts = re.fullmatch(r"(?:(\d+)h)?(?:(\d+)m)?(?:(\d+)s)?", duration)
    assert parts and duration, f"unreadable duration {duration!r}"
    hours, minutes, secs = (int(part or 0) for part in parts.groups())
    return hours * 3600.0 + minutes * 60.0 + secs


def ignored(path: str, patterns: list[str]) -> bool:
    """Docker's .dockerignore rule: the last pattern matching the path or a parent wins."""
    excluded = False
    parts = PurePosixPath(path).parts
    for pattern in patterns:
        negated = pattern.startswith("!")
        body = pattern.removeprefix("!").strip("/")
        regex = re.escape(body).replace(r"\*\*/", "(?:.*/)?").replace(r"\*\*", ".*")
        regex = regex.replace(r"\*", "[^/]*").replace(r"\?", "[^/]")
        prefixes = ("/".join(parts[:n]) for n in range(1, len(parts) + 1))
        if any(re.fullmatch(regex, prefix) for prefix in prefixes):
            excluded = not negated
    return excluded


# --- the CLI check catches what it should --------------------------------------------------------


@pytest.mark.parametrize(
    "args",
    [
        ["worker", "start", "--conect", "tcp/broker:7447"],
        ["worker", "begin", "--connect", "tcp/broker:7447"],
        ["analytic", "start", "--pop", "3"],
        ["analytic", "resume"],
        ["broker", "start", "--lease-seconds", "soon"],
    ],
)
def test_the_cli_check_rejects_what_the_cli_would(args: list[str]) -> None:
    with pytest.raises(click.UsageError):
        parse_invocation(args)


def test_the_cli_check_returns_the_parsed_options() -> None:
    name, params = parse_invocation(["broker", "status", "--connect", "tcp/h:1", "--json"])
    assert name == "status"
    assert params == {
        "connect": ("tcp/h:1",),
        "tls": None,
        "who": "broker",
        "as_json": True,
        "watch": False,
        "interval": 2.0,
    }


# --- compose.yaml ------------------------------------------------------------------------------


def test_compose_runs_a_broker_workers_and_an_analytic_from_one_image() -> None:
    services = compose()["services"]
    assert {"broker", "worker", "analytic"} <= set(services)
    images = {
        (spec["image"], json.dumps(spec["build"], sort_keys=True)) for spec in services.values()
    }
    assert len(images) == 1, "every service builds and runs the same image"


@pytest.mark.parametrize("name", ["broker", "worker", "analytic"])
def test_the_build_context_is_the_repo_root_and_the_dockerfile_exists(name: str) -> None:
    build = service(name)["build"]
    context = (COMPOSE_FILE.parent / build["context"]).resolve()
    assert context == ROOT
    assert (context / "pyproject.toml").is_file()
    dockerfile = (context / build["dockerfile"]).resolve()
    assert dockerfile == DOCKERFILE and dockerfile.is_file()
    # BuildKit reads <Dockerfile>.dockerignore beside a Dockerfile outside the context root.
    assert dockerfile.with_name(f"{dockerfile.name}.dockerignore").is_file()


@pytest.mark.parametrize(
    ("where", "args"), gainfarm_invocations(), ids=[where for where, _ in gainfarm_invocations()]
)
def test_every_command_is_a_valid_invocation_of_the_real_cli(where: str, args: list[str]) -> None:
    try:
        parse_invocation(args)
    except click.UsageError as error:
        pytest.fail(f"{where}: {shlex.join(args)}: {error.format_message()}")


def test_the_broker_listens_where_everyone_connects_and_publishes_that_port() -> None:
    name, params = parse_invocation(argv(service("broker")["command"]))
    assert name == "start"
    ((host, port),) = [endpoint(listen) for listen in params["listen"]]
    assert host == "0.0.0.0", "a container must listen beyond its loopback"
    assert port == FARM_PORT
    assert port in [container_port(mapping) for mapping in service("broker")["ports"]]
    for client in ("worker", "analytic"):
        _, client_params = parse_invocation(argv(service(client)["command"]))
        assert [endpoint(value) for value in client_params["connect"]] == [("broker", port)]


def test_the_broker_is_healthy_when_broker_status_answers_on_its_port() -> None:
    args = healthcheck_argv(service("broker")["healthcheck"])
    name, params = parse_invocation(args)
    assert args[0] == "broker" and name == "status"
    assert [endpoint(value) for value in params["connect"]] == [("127.0.0.1", FARM_PORT)]


def test_workers_scale_wait_for_a_healthy_broker_and_finish_their_episode_on_stop() -> None:
    worker = service("worker")
    assert "container_name" not in worker, "a fixed container name cannot be scaled"
    assert "ports" not in worker, "published ports would collide between replicas"
    _, params = parse_invocation(argv(worker["command"]))
    assert params["name"] is None, "replicas must get the HOST-PID default, not one fixed name"
    assert worker["depends_on"]["broker"]["condition"] == "service_healthy"
    assert worker["restart"] == "on-failure"
    assert seconds(worker["stop_grace_period"]) >= STOP_SECONDS


def test_the_analytic_is_a_one_shot_job_writing_into_the_runs_volume() -> None:
    analytic = service("analytic")
    assert analytic["profiles"], "not started by a plain `up`"
    assert analytic["restart"] == "no"  # quoted in YAML: a bare no would be the boolean
    assert analytic["depends_on"]["broker"]["condition"] == "service_healthy"
    name, params = parse_invocation(argv(analytic["command"]))
    assert name == "start" and params["connect"]
    mounts = [str(volume).split(":") for volume in analytic["volumes"]]
    named = [(source, target) for source, target, *_ in mounts if source in compose()["volumes"]]
    assert named, "the runs are kept in a named volume"
    assert any(params["out"].is_relative_to(target) for _, target in named)
    assert params["out"] != Path(named[0][1]), "a run directory inside the volume, not its root"


def test_every_compose_variable_has_a_default() -> None:
    for where, args in gainfarm_invocations():
        assert all("$" not in arg for arg in args), where


# --- compose.secure.yaml ------------------------------------------------------------------------


def test_the_secure_profile_overrides_only_services_of_the_farm() -> None:
    overrides = secure_overrides()["services"]
    assert set(overrides) - set(compose()["services"]) == {"certs"}
    assert secure_service("certs")["image"] == service("broker")["image"]


def _mounted(spec: dict, directory: Path) -> list[str]:
    """The volumes `spec` mounts at `directory`, as 'name' or 'name:ro'."""
    mounts = [str(volume).split(":") for volume in spec.get("volumes", [])]
    return [
        ":".join([source, *options])
        for source, target, *options in mounts
        if target == str(directory)
    ]


def test_the_secure_farm_speaks_tls_with_each_role_holding_the_generated_credentials() -> None:
    name, certs = parse_invocation(argv(secure_service("certs")["command"]))
    assert name == "certs" and certs["if_missing"], "every `up` runs it: it must keep the CA"
    credentials = certs["directory"]
    assert _mounted(secure_service("certs"), credentials) == ["certs"]
    assert "certs" in secure_overrides()["volumes"]

    broker = secure_service("broker")
    _, params = parse_invocation(argv(broker["command"]))
    assert [endpoint(value, "tls") for value in params["listen"]] == [("0.0.0.0", FARM_PORT)]
    assert params["tls"] == credentials
    assert broker["depends_on"]["certs"]["condition"] == "service_completed_successfully"
    _, check = parse_invocation(healthcheck_argv(broker["healthcheck"]))
    ((check_host, check_port),) = [endpoint(value, "tls") for value in check["connect"]]
    assert check_port == FARM_PORT and check["tls"] == credentials
    # Clients verify the broker's certificate against the name they dial.
    assert {"broker", check_host} <= set(certs["hosts"])

    for role in ("broker", "worker", "analytic"):
        spec = secure_service(role)
        assert _mounted(spec, credentials) == ["certs:ro"], role
        if role != "broker":
            _, params = parse_invocation(argv(spec["command"]))
            assert [endpoint(value, "tls") for value in params["connect"]] == [
                ("broker", FARM_PORT)
            ]
            assert params["tls"] == credentials
            assert spec["depends_on"]["broker"]["condition"] == "service_healthy"
    # Each process has an identity of its own, issued by the certs service: the worker's name is
    # its identity's (the router lets it lease under that name only), and the analytic picks the
    # only analytic identity there is.
    _, worker = parse_invocation(argv(secure_service("worker")["command"]))
    assert worker["name"] in certs["workers"]
    assert len(certs["analytics"]) == 1


def test_the_image_has_a_writable_place_for_the_credentials_volume() -> None:
    _, certs = parse_invocation(argv(secure_service("certs")["command"]))
    (run,) = [arguments for arguments in instruction("RUN") if "useradd" in arguments]
    assert (
        f"mkdir /runs {certs['directory']}" in run
        and str(certs["directory"]) in run.split("chown")[1]
    )


# --- the Dockerfile ----------------------------------------------------------------------------


def test_the_image_is_python_3_11() -> None:
    bases = [substitute(base, dockerfile_args()) for base in instruction("FROM")]
    assert bases
    for base in bases:
        assert re.fullmatch(r"python:3\.11(-slim)?(-\w+)?", base.split()[0]), base


def test_the_image_installs_the_project_from_the_context_with_the_learn_extra_only() -> None:
    mounts, command = pip_install()
    # The whole build context, mounted for the install: no layer keeps the source.
    (context,) = [mount for mount in mounts if "type=bind" in mount]
    fields = dict(field.partition("=")[::2] for field in context.split(","))
    assert "source" not in fields and "from" not in fields and "rw" in context.split(",")
    assert instruction("COPY") == [], "the source is mounted, not copied"
    at = command.index("install")
    options = shlex.split(substitute(" ".join(command[at + 1 :]), dockerfile_args()))
    targets = [arg for arg in options if not arg.startswith("-")]
    # The learn extra (Pinocchio, scikit-learn) lets a worker evaluate any feed-forward model a
    # job names; the test and dev tools stay out. Without build arguments pip has no options.
    assert targets == [f"{fields['target']}[learn]"], targets
    assert options == targets


def test_the_image_has_the_system_libraries_the_learn_extra_links() -> None:
    # Pinocchio's wheels link libgomp.so.1, which python:3.11-slim does not have.
    (run,) = [arguments for arguments in instruction("RUN") if "apt-get install" in arguments]
    assert "libgomp1" in run.split() and "rm -rf /var/lib/apt/lists/*" in run


def test_the_build_context_holds_what_pip_install_needs_and_nothing_else() -> None:
    ignore = DOCKERFILE.with_name("Dockerfile.dockerignore").read_text().splitlines()
    patterns = [line.strip() for line in ignore if line.strip() and not line.startswith("#")]
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    # Each package's folder: the package-dir mapping's, or its path under gainfarm/.
    mapped = project["tool"]["setuptools"]["package-dir"]
    folders = set()
    for package in project["tool"]["setuptools"]["packages"]:
        parent = max((name for name in mapped if package.startswith(name)), key=len)
        folders.add(mapped[parent] + package[len(parent) :].replace(".", "/"))
    needed = ["pyproject.toml", project["project"]["readme"]]
    for folder in sorted(folders):
        needed += [str(path.relative_to(ROOT)) for path in (ROOT / folder).glob("*")]
    needed = [path for path in needed if "__pycache__" not in path]
    assert "models/iiwa14.xml" in needed
    assert [path for path in needed if ignored(path, patterns)] == []
    for unwanted in (".git/HEAD", ".venv/bin/python", "runs/x/front.csv", "tests/conftest.py"):
        assert ignored(unwanted, patterns), unwanted
    assert ignored("worker/__pycache__/cli.cpython-311.pyc", patterns)


def test_the_image_runs_as_a_non_root_user() -> None:
    users = instruction("USER")
    assert users, "no USER: the container would run as root"
    assert users[-1].split(":")[0] not in ("root", "0")


def test_the_default_command_is_a_broker_on_the_exposed_port() -> None:
    name, params = parse_invocation(dockerfile_cmd())
    assert dockerfile_cmd()[0] == "broker" and name == "start"
    assert [endpoint(value)[1] for value in params["listen"]] == [FARM_PORT]
    assert instruction("EXPOSE") == [str(FARM_PORT)]
    assert instruction("ENTRYPOINT") == [], "the command alone picks the role"


# --- the README --------------------------------------------------------------------------------


def test_the_readme_compose_commands_use_this_compose_file_and_its_services() -> None:
    services = compose()["services"]
    profiles = {profile for spec in services.values() for profile in spec.get("profiles", [])}
    count = 0
    for tokens in readme_commands():
        for segment in segments(tokens):
            if "compose" not in segment:
                continue
            at = segment.index("compose")
            assert segment[at - 1 : at + 2] == ["docker", "compose", "-f"], segment
            assert (ROOT / segment[at + 2]).resolve() == COMPOSE_FILE, segment
            count += 1
            rest = segment[at + 3 :]
            known = set(services)
            if rest[0] == "-f":  # the secure profile goes over the base file
                assert (ROOT / rest[1]).resolve() == SECURE_FILE, segment
                known |= set(secure_overrides()["services"])
                rest = rest[2:]
            while rest[0] == "--profile":
                assert rest[1] in profiles, segment
                rest = rest[2:]
            verb, *args = rest
            if verb in ("run", "exec"):
                assert next(arg for arg in args if not arg.startswith("-")) in known, segment
            for flag, value in itertools.pairwise(args):
                if flag == "--scale":
                    assert value.split("=")[0] in services, segment
    assert count >= 5


def test_the_readme_documents_the_farm_up_scaled_and_a_run() -> None:
    commands = [shlex.join(tokens) for tokens in readme_commands()]
    assert any(" up " in command and "--scale worker=" in command for command in commands)
    assert any("run --rm analytic" in command for command in commands)


def test_every_gainfarm_command_in_the_readme_is_valid() -> None:
    seen = set()
    resumed = []
    for tokens in readme_commands():
        for segment in segments(tokens):
            for index, token in enumerate(segment[:-1]):
                group = PROGRAMS.get(token)
                if group is None or segment[index + 1] not in group.commands:
                    continue  # e.g. a service name, or `--scale worker=8`
                args = segment[index:]
                try:
                    name, params = parse_invocation(args)
                except click.UsageError as error:
                    pytest.fail(f"README: {shlex.join(args)}: {error.format_message()}")
                seen.add((token, name))
                if name == "resume":
                    resumed.append(params["run_dir"])
                break
    assert {
        ("worker", "start"),
        ("broker", "status"),
        ("analytic", "start"),
        ("analytic", "resume"),
        ("analytic", "experiment"),
    } <= seen
    # The resume example continues the run the analytic service starts by default.
    _, params = parse_invocation(argv(service("analytic")["command"]))
    assert params["out"] in resumed


# --- docker/e2e.py: the stand-in path differs from the public one only where it must -----------


def test_the_e2e_build_sets_only_the_base_and_pip_with_no_index() -> None:
    e2e = load_e2e()
    defaults = dockerfile_args()
    # Without build arguments: Docker Hub's image, and pip with its index.
    assert defaults == {"BASE": "python:3.11-slim", "PIP_OPTIONS": ""}
    stand_in = e2e.build_args("gainfarm-e2e-base:tag")
    assert set(stand_in) == set(defaults)
    assert [substitute(base, stand_in) for base in instruction("FROM")] == [stand_in["BASE"]]
    mounts, command = pip_install()
    (context,) = [mount for mount in mounts if "type=bind" in mount]
    target = dict(field.partition("=")[::2] for field in context.split(","))["target"]
    options = shlex.split(substitute(" ".join(command[command.index("install") + 1 :]), stand_in))
    wheels = f"{target}/{e2e.CONTEXT_WHEELS}"
    assert options == ["--no-index", "--find-links", wheels, f"{target}[learn]"]
    # The wheels reach the build context, and never git.
    patterns = [
        line.strip()
        for line in DOCKERFILE.with_name("Dockerfile.dockerignore").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    assert not ignored(f"{e2e.CONTEXT_WHEELS}/numpy-2.0-cp311-manylinux_2_28_x86_64.whl", patterns)
    gitignore = (DOCKER / ".gitignore").read_text().split()
    assert f"{Path(e2e.CONTEXT_WHEELS).name}/" in gitignore
    assert service("broker")["image"] == e2e.IMAGE


def test_the_e2e_compose_file_is_compose_yaml_but_for_its_name() -> None:
    e2e = load_e2e()
    assert "name" in compose(), "Compose v2 users keep the fixed project name"
    for_v1 = yaml.safe_load(e2e.compose_for_v1(COMPOSE_FILE.read_text()))
    assert for_v1 == {key: value for key, value in compose().items() if key != "name"}


def test_the_e2e_runs_the_compose_commands_only_smaller() -> None:
    e2e = load_e2e()
    env = e2e.farm_env(17447) | {"RUN": "tune"}
    text = COMPOSE_FILE.read_text() + SECURE_FILE.read_text()
    assert set(env) <= set(re.findall(r"\$\{(\w+)", text)), "only variables the files read"
    for spec in (service("analytic"), secure_service("analytic")):
        _, public = parse_invocation(argv(spec["command"]))
        _, small = parse_invocation(argv(spec["command"], env))
        changed = {key for key in public if public[key] != small[key]}
        assert changed == {"pop", "generations", "duration"}
        assert (small["pop"], small["generations"]) == (e2e.POP, e2e.GENERATIONS)
    (published,) = service("broker")["ports"]
    assert interpolate(published, env) == f"17447:{FARM_PORT}"
    assert interpolate(published) == f"{FARM_PORT}:{FARM_PORT}"


def test_the_e2e_adds_secure_workers_and_asks_the_status_as_the_docs_do() -> None:
    e2e = load_e2e()
    _, ours = parse_invocation(argv(secure_service("certs")["command"]))
    _, theirs = parse_invocation(e2e.CERTS_COMMAND)
    assert {key for key in ours if ours[key] != theirs[key]} == {"workers"}
    assert theirs["workers"][: len(ours["workers"])] == ours["workers"]
    assert theirs["workers"] == e2e.SECURE_WORKERS
    _, worker = parse_invocation(argv(secure_service("worker")["command"]))
    _, added = parse_invocation(e2e.secure_worker_command("cobot-2"))
    assert {key for key in worker if worker[key] != added[key]} == {"name"}
    # docker/README.md starts an added worker with the same command.
    assert any(
        tokens[-len(e2e.secure_worker_command("cobot-2")) :] == e2e.secure_worker_command("cobot-2")
        for tokens in readme_commands()
    )
    for status, spec in (
        (e2e.PLAIN_STATUS, service("broker")),
        (e2e.SECURE_STATUS, secure_service("broker")),
    ):
        _, check = parse_invocation(healthcheck_argv(spec["healthcheck"]))
        _, asked = parse_invocation(status)
        assert {key for key in check if check[key] != asked[key]} <= {"as_json"}
