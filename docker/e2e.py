"""The compose farm of docker/README.md, run for real on a container engine, end to end.

    .venv/bin/python docker/e2e.py     # as root, with Python 3.11 and its pip (the project's venv)

Made for a machine that reaches Debian's and Python's package registries and no container
registry. It installs a container engine from Debian's packages if one is missing and starts a
daemon of its own (its own socket, data root and containerd namespace: a host's Docker is never
touched). It builds a stand-in for `python:3.11-slim` from Debian 12's packages (its python3 is
3.11), fetches the project's wheels on this host, and builds docker/Dockerfile with them and no
package index. Then, with docker/compose.yaml as it is but for its top-level `name:` (Debian's
Compose 1.29 refuses it; the project is named with --project-name instead):

1. a broker and three workers, and a small tuning run (`run --rm analytic`) to its end: its run
   directory is checked, and every worker did jobs of it;
2. two tuning runs at once, into directories of one name, started while no worker is up so that
   both are queued on the broker together: they must hold distinct study names, and both finish;
3. the secure profile (compose.secure.yaml over it): its `up`, two more workers added as
   docker/README.md says, and a run as analytic `dev`, checked the same way.

Whatever happens, everything it started is torn down: containers, volumes, networks, the image,
the daemon. The engine, the stand-in base image and the wheels stay for the next run (--state).
What differs from a build and a farm with Docker Hub and Compose v2 is build_args(), the dropped
`name:` (compose_for_v1) and the variables the farm is given (farm_env);
tests/docker/test_compose.py checks that nothing else does.

Exit status: 0 everything checked; 1 a step or a check failed (the last line says which, and
names the step's log); 77 no container engine can run here (the last line says why: the test
skips with it); 2 bad usage. It imports the standard library only (its pip runs as a command):
it runs before anything else is installed.
"""

import argparse
import contextlib
import csv
import fcntl
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

REPO = Path(__file__).resolve().parents[1]
DOCKER_DIR = REPO / "docker"
SKIP = 77  # automake's code for "skipped": no engine can run here
DEFAULT_STATE = Path("/var/lib/gainfarm-e2e")

# The engine: the commands needed, and the Debian package of each.
PACKAGES = {"dockerd": "docker.io", "docker-compose": "docker-compose", "mmdebstrap": "mmdebstrap"}
# Debian's docker.io CLI: BuildKit built in (a newer CLI elsewhere on the PATH may want buildx).
DOCKER_CLI = Path("/usr/bin/docker")
RUNTIME = Path("/run/gainfarm-e2e")  # the daemon's socket, pid file and exec root

# The stand-in for python:3.11-slim: Debian 12's python3 in a venv first on the PATH, so `python`
# and `pip` are 3.11's and console scripts land on the PATH, as in the official image.
BASE_BOOTSTRAP = (
    "mmdebstrap",
    "--quiet",
    "--variant=minbase",
    "--include=python3,python3-venv",
    '--customize-hook=chroot "$1" python3 -m venv /opt/venv',
    "bookworm",
    "-",  # a tarball on stdout, for `docker import`
)
BASE_CHANGES = (
    "ENV PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
    "ENV LANG=C.UTF-8",
    'CMD ["python3"]',
)
BASE_REPOSITORY = "gainfarm-e2e-base"

IMAGE = "gainfarm:latest"  # the image compose.yaml names
# The wheels enter the build context here (Dockerfile.dockerignore lets them in); the Dockerfile
# mounts the context at /tmp/gainfarm for its pip install.
CONTEXT_WHEELS = "docker/wheels"
PROJECT = "gainfarm-e2e"

# Small runs, so that the whole test takes minutes; 3 s is about the shortest spiral the iiwa's
# speed limits allow. ARGS comes after the compose command's options, and the last one wins.
POP, GENERATIONS = 8, 2
RUN_ARGS = f"--pop {POP} --generations {GENERATIONS} --duration 3"
WORKERS = 3
TWINS = ("twin-1/tune", "twin-2/tune")  # one directory name: one slug in both study names
# The secure profile's workers: cobot-1 is the compose file's; the others are added as
# docker/README.md says: issued by `broker certs` with more --worker, started by name.
SECURE_WORKERS = ("cobot-1", "cobot-2", "cobot-3")
CERTS_COMMAND = [
    *("broker", "certs", "/certs", "--if-missing", "--host", "broker", "--host", "localhost"),
    *("--analytic", "dev"),
    *[option for name in SECURE_WORKERS for option in ("--worker", name)],
]


def secure_worker_command(name: str) -> list[str]:
    return ["worker", "start", "--connect", "tls/broker:7447", "--tls", "/certs", "--name", name]


PLAIN_STATUS = ["broker", "status", "--connect", "tcp/127.0.0.1:7447"]
SECURE_STATUS = ["broker", "status", "--connect", "tls/localhost:7447", "--tls", "/certs"]
MCAP_MAGIC = b"\x89MCAP0\r\n"  # an MCAP file starts and ends with it
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
IMAGE_USER = 10001  # the Dockerfile's USER: every file of a run is its
RUN_FILES = (
    "run.json",
    "config.json",
    "history.csv",
    "front.csv",
    "front.json",
    "evaluated.csv",
    "report.md",
    "pareto.png",
    "hypervolume.png",
)


class Skip(Exception):
    """No container engine can run here."""


class Failure(Exception):
    """A step or a check failed."""


class Terminated(Exception):
    """SIGTERM: stop, through the teardown."""


def terminate(signum: int, frame: object) -> None:
    raise Terminated


def say(message: str) -> None:
    print(f"e2e: {message}", flush=True)


def build_args(base: str) -> dict[str, str]:
    """The Dockerfile's build arguments here: the stand-in base, and pip with no index."""
    return {"BASE": base, "PIP_OPTIONS": f"--no-index --find-links /tmp/gainfarm/{CONTEXT_WHEELS}"}


def compose_for_v1(text: str) -> str:
    """compose.yaml for Compose 1.29: without the top-level `name:`, which it refuses."""
    lines = text.splitlines(keepends=True)
    return "".join(line for line in lines if not line.startswith("name:"))


def farm_env(broker_port: int) -> dict[str, str]:
    """The variables compose.yaml reads, as this test sets them (RUN is set per run)."""
    return {"BROKER_PORT": str(broker_port), "ARGS": RUN_ARGS}


# --- running commands --------------------------------------------------------------------------


def last_line(log: Path) -> str:
    lines = [line.strip() for line in log.read_text(errors="replace").splitlines()]
    return next((line for line in reversed(lines) if line), "(no output)")


class Shell:
    """Runs the steps' commands with the engine's environment, each one's output in a log file of
    its own, named when it fails."""

    def __init__(self, logs: Path, socket_path: Path):
        self.logs = logs
        self.count = 0
        # None of the caller's Docker or Compose settings (a context, a project, RUN, ARGS) may
        # steer this test's engine or farm.
        inherited = {
            key: value
            for key, value in os.environ.items()
            if not key.startswith(("DOCKER_", "COMPOSE_")) and key not in ("RUN", "ARGS")
        }
        self.env = inherited | {"DOCKER_HOST": f"unix://{socket_path}", "DOCKER_BUILDKIT": "1"}

    def log_file(self, name: str) -> Path:
        self.count += 1
        return self.logs / f"{self.count:03d}-{name}.log"

    def run(
        self,
        name: str,
        argv: list[str],
        timeout: float,
        env: dict[str, str] | None = None,
        check: bool = True,
        stdout: int | IO[bytes] | None = None,
    ) -> subprocess.CompletedProcess[bytes]:
        """Run `argv` to its end: Failure if it fails (with `check`) or overruns `timeout`."""
        log = self.log_file(name)
        with log.open("wb") as output:
            output.write(f"$ {' '.join(argv)}\n".encode())
            output.flush()
            try:
                done = subprocess.run(
                    argv,
                    stdin=subprocess.DEVNULL,
                    stdout=output if stdout is None else stdout,
                    stderr=output,
                    env=self.env | (env or {}),
                    timeout=timeout,
                    check=False,
                )
            except subprocess.TimeoutExpired:
                raise Failure(f"{name}: still running after {timeout:.0f} s ({log})") from None
        if check and done.returncode != 0:
            raise Failure(f"{name}: exit {done.returncode}: {last_line(log)} ({log})")
        return done

    def output(
        self, name: str, argv: list[str], timeout: float, env: dict[str, str] | None = None
    ) -> str:
        """What `argv` prints on stdout."""
        return self.run(name, argv, timeout, env=env, stdout=subprocess.PIPE).stdout.decode()

    def start(self, name: str, argv: list[str], env: dict[str, str]) -> "Background":
        log = self.log_file(name)
        output = log.open("wb")
        process = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=output, stderr=output, env=self.env | env
        )
        return Background(name, process, log, output)


class Background:
    """A command left running while the test goes on."""

    def __init__(self, name: str, process: subprocess.Popen, log: Path, output: IO[bytes]):
        self.name, self.process, self.log, self.output = name, process, log, output

    def wait(self, timeout: float) -> None:
        try:
            code = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            raise Failure(
                f"{self.name}: still running after {timeout:.0f} s ({self.log})"
            ) from None
        if code != 0:
            raise Failure(f"{self.name}: exit {code}: {last_line(self.log)} ({self.log})")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(30)
        self.output.close()


def wait_until(what: str, ready: Callable[[], bool], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not ready():
        if time.monotonic() > deadline:
            raise Failure(f"no {what} after {timeout:.0f} s")
        time.sleep(1)


def free_port() -> int:
    """A TCP port free on every address, for the broker's published port: a farm or a test that
    uses 7447 here is left alone."""
    with socket.socket() as probe:
        probe.bind(("", 0))
        return probe.getsockname()[1]


# --- the engine --------------------------------------------------------------------------------


def install_engine(shell: Shell) -> None:
    """Debian's packages for the commands missing; Skip if they cannot be installed."""
    missing = {package for command, package in PACKAGES.items() if not shutil.which(command)}
    if not DOCKER_CLI.exists():
        missing.add("docker.io")
    if not missing:
        return
    listed = ", ".join(sorted(missing))
    if os.geteuid() != 0:
        raise Skip(f"needs root to install {listed} (Debian packages)")
    if not shutil.which("apt-get"):
        raise Skip(f"no apt-get to install {listed} with")
    say(f"installing {listed} (Debian packages)")
    env = {"DEBIAN_FRONTEND": "noninteractive"}
    # Another apt or dpkg at work (an unattended upgrade, say) is waited for, not a failure.
    apt = ["apt-get", "-q", "-o", "DPkg::Lock::Timeout=600"]
    try:
        shell.run("apt-update", [*apt, "update"], 900, env=env)
        install = [*apt, "install", "-y", "--no-install-recommends", *sorted(missing)]
        shell.run("apt-install", install, 1500, env=env)
    except Failure as error:
        raise Skip(f"cannot install the container engine: {error}") from None


class Daemon:
    """A dockerd of this test's own: its socket, exec root, data root and containerd namespace;
    no default bridge, no iptables rules and no forwarding, so the farm's containers reach each
    other over their compose network and nothing beyond this host."""

    def __init__(self, state: Path):
        self.data_root = state / "docker"
        self.socket = RUNTIME / "docker.sock"
        self.pid_file = RUNTIME / "dockerd.pid"
        self.log = state / "dockerd.log"
        self.process: subprocess.Popen | None = None

    def start(self, shell: Shell) -> str:
        """Start it and return the storage driver it chose; Skip if it cannot run."""
        if os.geteuid() != 0:
            raise Skip("needs root to run a container engine")
        self.stop_leftover()
        RUNTIME.mkdir(parents=True, exist_ok=True)
        self.data_root.mkdir(parents=True, exist_ok=True)
        argv = [
            "dockerd",
            f"--data-root={self.data_root}",
            f"--exec-root={RUNTIME / 'exec'}",
            f"--host=unix://{self.socket}",
            f"--pidfile={self.pid_file}",
            "--bridge=none",
            "--iptables=false",
            "--ip-forward=false",
            f"--containerd-namespace={PROJECT}",
            f"--containerd-plugins-namespace={PROJECT}-plugins",
        ]
        with self.log.open("wb") as output:
            # A session of its own: a Ctrl-C meant for this script must not stop the daemon
            # before the teardown has used it.
            self.process = subprocess.Popen(
                argv, stdin=subprocess.DEVNULL, stdout=output, stderr=output, start_new_session=True
            )
        deadline = time.monotonic() + 60
        info = [str(DOCKER_CLI), "info", "--format", "{{.Driver}}"]
        while True:
            if self.process.poll() is not None:
                raise Skip(f"dockerd exited ({self.process.returncode}): {self.reason()}")
            answer = subprocess.run(
                info, capture_output=True, env=shell.env, timeout=30, check=False
            )
            if answer.returncode == 0:
                return answer.stdout.decode().strip()
            if time.monotonic() > deadline:
                raise Skip(f"dockerd did not answer within 60 s: {self.reason()}")
            time.sleep(1)

    def reason(self) -> str:
        """The daemon's last error, from its log."""
        lines = self.log.read_text(errors="replace").splitlines()
        errors = [line for line in lines if "level=fatal" in line or "level=error" in line]
        return (errors or lines or ["no output"])[-1].strip()

    def stop_leftover(self) -> None:
        """A daemon that a killed run of this test left holds the pid file: stop it."""
        try:
            pid = int(self.pid_file.read_text())
            command = Path(f"/proc/{pid}/cmdline").read_bytes()
        except (OSError, ValueError):
            return
        if b"dockerd" in command and str(self.socket).encode() in command:
            say(f"stopping the daemon a killed run left (pid {pid})")
            os.kill(pid, signal.SIGTERM)
            wait_until("end of that daemon", lambda: not Path(f"/proc/{pid}").exists(), 90)

    def stop(self) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        self.process.terminate()
        try:
            self.process.wait(90)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(30)


def remove_project(shell: Shell) -> None:
    """Every container, volume and network of the test's compose project, whatever state a
    step left them in (compose's own `down` ran already if the step got that far)."""
    docker = str(DOCKER_CLI)
    label = f"label=com.docker.compose.project={PROJECT}"
    for kind, listing, removal in (
        ("container", ["ps", "--all", "--quiet"], ["rm", "--force", "--volumes"]),
        ("volume", ["volume", "ls", "--quiet"], ["volume", "rm", "--force"]),
        ("network", ["network", "ls", "--quiet"], ["network", "rm"]),
    ):
        found = shell.output(f"list-{kind}s", [docker, *listing, "--filter", label], 60).split()
        if found:
            shell.run(f"remove-{kind}s", [docker, *removal, *found], 120)


# --- the image ---------------------------------------------------------------------------------


def base_image(shell: Shell) -> str:
    """The stand-in base image, made once per recipe and kept in the daemon's data root."""
    recipe = hashlib.sha256(json.dumps([BASE_BOOTSTRAP, BASE_CHANGES]).encode()).hexdigest()
    name = f"{BASE_REPOSITORY}:{recipe[:12]}"
    docker = str(DOCKER_CLI)
    if shell.run("base-inspect", [docker, "image", "inspect", name], 60, check=False).returncode:
        say(f"making the stand-in base image {name} (mmdebstrap, Debian 12)")
        log = shell.log_file("base")
        changes = [option for change in BASE_CHANGES for option in ("--change", change)]
        with log.open("wb") as output:
            bootstrap = subprocess.Popen(
                BASE_BOOTSTRAP, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=output
            )
            assert bootstrap.stdout is not None
            try:
                imported = subprocess.run(
                    [docker, "import", *changes, "-", name],
                    stdin=bootstrap.stdout,
                    stdout=output,
                    stderr=output,
                    env=shell.env,
                    timeout=900,
                    check=False,
                )
            except subprocess.TimeoutExpired:
                raise Failure(f"the stand-in base image: still going after 900 s ({log})") from None
            finally:
                bootstrap.stdout.close()
                try:
                    bootstrap.wait(60)
                except subprocess.TimeoutExpired:
                    bootstrap.kill()
                    bootstrap.wait()
        if bootstrap.returncode != 0 or imported.returncode != 0:
            raise Failure(f"the stand-in base image: {last_line(log)} ({log})")
        # The bases of earlier recipes are of no more use.
        listing = [docker, "image", "ls", BASE_REPOSITORY, "--format", "{{.Repository}}:{{.Tag}}"]
        for old in set(shell.output("base-list", listing, 60).split()) - {name}:
            shell.run("base-remove", [docker, "image", "rm", old], 120, check=False)
    # The first container: if none can run here, there is no engine to test with.
    try:
        shell.run("container", [docker, "run", "--rm", "--network=none", name, "true"], 120)
    except Failure as error:
        raise Skip(f"containers cannot run here: {error}") from None
    return name


def wheels(shell: Shell, state: Path) -> Path:
    """The project's wheels with the learn extra, and its build requirements (pip installs them
    for the build), fetched with this Python (3.11, the stand-in's); kept while pyproject.toml
    stays the same."""
    pyproject = (REPO / "pyproject.toml").read_bytes()
    stamp = hashlib.sha256(pyproject + sys.version.encode()).hexdigest()
    directory = state / "wheels"
    if (directory / ".stamp").is_file() and (directory / ".stamp").read_text() == stamp:
        return directory
    say("fetching the project's wheels")
    fresh = Path(tempfile.mkdtemp(prefix="wheels-", dir=state))
    try:
        requires = tomllib.loads(pyproject.decode())["build-system"]["requires"]
        download = [sys.executable, "-m", "pip", "download", "--quiet", "--only-binary=:all:"]
        download += ["--dest", str(fresh), f"{REPO}[learn]", *requires]
        shell.run("wheels", download, 900)
        (fresh / ".stamp").write_text(stamp)
        shutil.rmtree(directory, ignore_errors=True)
        fresh.rename(directory)  # whole, or not at all
    finally:
        shutil.rmtree(fresh, ignore_errors=True)
    return directory


@contextlib.contextmanager
def wheels_in_context(source: Path) -> Iterator[None]:
    """The wheels inside the build context while the build runs (hard links where possible)."""
    target = REPO / CONTEXT_WHEELS
    shutil.rmtree(target, ignore_errors=True)
    target.mkdir(parents=True)
    try:
        for wheel in source.glob("*.whl"):
            try:
                os.link(wheel, target / wheel.name)
            except OSError:  # another file system
                shutil.copy2(wheel, target / wheel.name)
        yield
    finally:
        shutil.rmtree(target, ignore_errors=True)


def build(shell: Shell, base: str, wheel_dir: Path) -> None:
    """docker/Dockerfile as it is, with build_args(). The build has the host's network, for apt
    and Debian's mirror; pip has no index."""
    say(f"building {IMAGE} from {base}")
    arguments = [f"--build-arg={key}={value}" for key, value in build_args(base).items()]
    command = [str(DOCKER_CLI), "build", "--progress=plain", "--network=host", *arguments]
    command += ["--file", str(DOCKER_DIR / "Dockerfile"), "--tag", IMAGE, str(REPO)]
    with wheels_in_context(wheel_dir):
        shell.run("build", command, 1800)
    # The learn extra's native libraries load (a worker may be sent a linear feed-forward), and
    # the image runs as its own user.
    probe = "import os, mujoco, zenoh, pyarrow, pinocchio, sklearn; print(os.getuid())"
    run = [str(DOCKER_CLI), "run", "--rm", "--network=none", IMAGE, "python", "-c", probe]
    uid = shell.output("image-probe", run, 120).strip()
    if uid != str(IMAGE_USER):
        raise Failure(f"the image runs as uid {uid}, not {IMAGE_USER}")


# --- the farm ----------------------------------------------------------------------------------


class Farm:
    """The compose project over `files`, driven as docker/README.md drives it."""

    def __init__(self, shell: Shell, files: list[Path], env: dict[str, str], status: list[str]):
        self.shell = shell
        self.env = env
        self.status_command = status
        self.prefix = [shutil.which("docker-compose") or "docker-compose"]
        self.prefix += ["--project-name", PROJECT, "--project-directory", str(DOCKER_DIR)]
        for file in files:
            self.prefix += ["--file", str(file)]

    def compose(
        self, name: str, *args: str, timeout: float = 300, env: dict[str, str] | None = None
    ) -> None:
        self.shell.run(name, [*self.prefix, *args], timeout, env=self.env | (env or {}))

    def status(self) -> dict:
        """The broker's status, asked inside its container as docker/README.md does."""
        command = [*self.prefix, "exec", "-T", "broker", *self.status_command, "--json"]
        return json.loads(self.shell.output("status", command, 60, env=self.env))

    def workers(self, count: int) -> dict[str, int]:
        """Once `count` workers are connected: each one's jobs done."""
        found: dict[str, int] = {}

        def connected() -> bool:
            found.clear()
            found.update({w["name"]: w["jobs_done"] for w in self.status()["workers"]})
            return len(found) == count

        wait_until(f"{count} workers on the broker", connected, 180)
        return found

    def tune(self, run: str) -> None:
        """The compose file's tuning run, with ARGS, to its end."""
        slug = run.replace("/", "-")
        self.compose(f"run-{slug}", "run", "--rm", "-T", "analytic", env={"RUN": run}, timeout=900)

    def start_tune(self, run: str) -> Background:
        argv = [*self.prefix, "run", "--rm", "-T", "analytic"]
        return self.shell.start(f"run-{run.replace('/', '-')}", argv, self.env | {"RUN": run})

    def fetch(self, run: str, into: Path) -> Path:
        """A run directory out of the runs volume as a tar stream, as docker/README.md does."""
        archive = into / f"{run.replace('/', '-')}.tar"
        tar = ["run", "--rm", "--no-deps", "-T", "analytic", "tar", "-C", "/runs", "-c", run]
        with archive.open("wb") as output:
            self.shell.run("fetch", [*self.prefix, *tar], 300, env=self.env, stdout=output)
        self.shell.run("untar", ["tar", "-x", "-C", str(into), "-f", str(archive)], 120)
        archive.unlink()
        return into / run

    def down(self) -> None:
        self.compose("down", "down", "--volumes", "--remove-orphans", "--timeout", "30")


def check_run(directory: Path, owner: int = IMAGE_USER) -> None:
    """A finished run of RUN_ARGS, its every file `owner`'s: its records, every episode's log,
    the figures, the report."""

    def expect(condition: bool, what: str) -> None:
        if not condition:
            raise Failure(f"run {directory}: {what}")

    for name in RUN_FILES:
        expect((directory / name).is_file(), f"no {name}")
    config = json.loads((directory / "config.json").read_text())
    expect((config["pop"], config["generations"]) == (POP, GENERATIONS), "not RUN_ARGS' config")
    with (directory / "history.csv").open() as file:
        history = list(csv.DictReader(file))
    evaluations = POP * GENERATIONS
    expect(len(history) == GENERATIONS, f"{len(history)} generations in history.csv")
    expect(int(history[-1]["evaluations"]) == evaluations, "evaluations in history.csv")
    with (directory / "evaluated.csv").open() as file:
        expect(len(list(csv.DictReader(file))) == evaluations, "rows of evaluated.csv")
    with (directory / "front.csv").open() as file:
        front = list(csv.DictReader(file))
    members = json.loads((directory / "front.json").read_text())["members"]
    expect(len(front) >= 1 and len(members) == len(front), "front.csv and front.json disagree")
    # The logs kept, each under its job id (generation, candidate, trajectory), whole: every
    # job's and the default gains' with --keep all, else (--keep front, the default) the front's.
    if config["keep"] == "all":
        kept = {f"g{g:04d}-c{c:03d}-t0.mcap" for g in range(GENERATIONS) for c in range(POP)}
        kept.add("baseline-t0.mcap")
    else:
        kept = {Path(log).name for member in members for log in member["logs"]}
    logs = {path.name: path.read_bytes() for path in (directory / "episodes").iterdir()}
    expect(len(kept) >= 1 and set(logs) == kept, f"episodes/ holds {sorted(logs)}")
    for name, content in logs.items():
        whole = content.startswith(MCAP_MAGIC) and content.endswith(MCAP_MAGIC)
        expect(whole, f"episodes/{name} is not a whole MCAP file")
    for member in members:
        expect(all((directory / log).is_file() for log in member["logs"]), f"{member['logs']}")
    for figure in ("pareto.png", "hypervolume.png"):
        expect((directory / figure).read_bytes().startswith(PNG_MAGIC), f"{figure} is no PNG")
    expect(f"evaluations: {evaluations}" in (directory / "report.md").read_text(), "report.md")
    owners = {path.stat().st_uid for path in [directory, *directory.rglob("*")]}
    expect(owners == {owner}, f"files owned by uids {owners}, not {owner}")


def check_every_worker_worked(before: dict[str, int], after: dict[str, int]) -> None:
    if set(after) != set(before):
        raise Failure(f"the workers changed during the run: {sorted(before)} -> {sorted(after)}")
    idle = sorted(name for name in before if after[name] <= before[name])
    if idle:
        raise Failure(f"workers that did no job of the run: {idle} ({after})")


def plain(shell: Shell, compose_file: Path, env: dict[str, str], runs: Path) -> None:
    """compose.yaml: three workers and a run; then two runs at once."""
    farm = Farm(shell, [compose_file], env, PLAIN_STATUS)
    say(f"plain farm: up, {WORKERS} workers, a run")
    farm.compose("up", "up", "--detach", "--no-build", "--scale", f"worker={WORKERS}")
    before = farm.workers(WORKERS)
    farm.tune("tune")
    check_every_worker_worked(before, farm.workers(WORKERS))
    check_run(farm.fetch("tune", runs))

    # Two runs at once: with the workers stopped, both studies must be open and queued on the
    # broker together before any job runs; their directories have one name, so one slug.
    say("plain farm: two runs at once")
    farm.compose("stop-workers", "stop", "worker")
    wait_until("worker left", lambda: farm.status()["worker_count"] == 0, 120)
    twins = [farm.start_tune(run) for run in TWINS]
    try:
        studies: dict[str, int] = {}

        def both_queued() -> bool:
            studies.clear()
            studies.update({s["name"]: s["queued"] for s in farm.status()["studies"]})
            return len(studies) == len(TWINS) and all(studies.values())

        wait_until("two studies queued at once", both_queued, 300)
        if not all(name.startswith("tune-") for name in studies):
            raise Failure(f"study names {sorted(studies)}: not named after their directories")
        say(f"plain farm: studies {' and '.join(sorted(studies))} queued at once")
        farm.compose("start-workers", "start", "worker")
        for twin in twins:
            twin.wait(900)
    finally:
        for twin in twins:
            twin.stop()
    for run in TWINS:
        check_run(farm.fetch(run, runs))
    farm.down()


def secure(shell: Shell, compose_file: Path, env: dict[str, str], runs: Path) -> None:
    """compose.yaml with compose.secure.yaml: workers added as docker/README.md says, a run."""
    files = [compose_file, DOCKER_DIR / "compose.secure.yaml"]
    farm = Farm(shell, files, env, SECURE_STATUS)
    say(f"secure farm: up, {len(SECURE_WORKERS)} workers, a run as analytic dev")
    farm.compose("up", "up", "--detach", "--no-build")
    farm.compose("certs", "run", "--rm", "-T", "certs", *CERTS_COMMAND)
    farm.compose("restart-broker", "restart", "broker")
    for name in SECURE_WORKERS[1:]:
        farm.compose(f"add-{name}", "run", "--detach", "worker", *secure_worker_command(name))
    before = farm.workers(len(SECURE_WORKERS))
    if set(before) != set(SECURE_WORKERS):
        raise Failure(f"secure workers {sorted(before)}, not {list(SECURE_WORKERS)}")
    farm.tune("secure")
    check_every_worker_worked(before, farm.workers(len(SECURE_WORKERS)))
    check_run(farm.fetch("secure", runs))
    farm.down()


# --- the whole test ----------------------------------------------------------------------------


class Clock:
    """How long each phase took, for the last line."""

    def __init__(self) -> None:
        self.phases: dict[str, float] = {}
        self.started = time.monotonic()

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        started = time.monotonic()
        try:
            yield
        finally:
            self.phases[name] = time.monotonic() - started

    def summary(self) -> str:
        phases = ", ".join(f"{name} {seconds:.0f} s" for name, seconds in self.phases.items())
        return f"{time.monotonic() - self.started:.0f} s ({phases})"


def end_to_end(state: Path, keep_runs: Path | None) -> str:
    clock = Clock()
    logs = state / "logs"
    shutil.rmtree(logs, ignore_errors=True)
    logs.mkdir(parents=True)
    shell = Shell(logs, RUNTIME / "docker.sock")
    daemon = Daemon(state)
    work = Path(tempfile.mkdtemp(prefix="gainfarm-e2e-"))
    try:
        with clock.phase("engine"):
            install_engine(shell)
            driver = daemon.start(shell)
            say(f"engine: dockerd, {driver} storage, on {daemon.socket}; logs in {logs}")
            remove_project(shell)  # what a killed run left
        with clock.phase("base image"):
            base = base_image(shell)
        with clock.phase("wheels"):
            wheel_dir = wheels(shell, state)
        with clock.phase("build"):
            build(shell, base, wheel_dir)
        compose_file = work / "compose.yaml"
        compose_file.write_text(compose_for_v1((DOCKER_DIR / "compose.yaml").read_text()))
        runs = keep_runs or work / "runs"
        runs.mkdir(parents=True, exist_ok=True)
        env = farm_env(free_port())
        with clock.phase("plain farm"):
            plain(shell, compose_file, env, runs)
        with clock.phase("secure farm"):
            secure(shell, compose_file, env, runs)
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the teardown runs to its end
        with clock.phase("teardown"):
            teardown(shell, daemon)
            shutil.rmtree(work, ignore_errors=True)
    return clock.summary()


def teardown(shell: Shell, daemon: Daemon) -> None:
    """Everything this run started goes; the base image stays in the data root."""
    if daemon.process is not None and daemon.process.poll() is None:
        docker = str(DOCKER_CLI)
        for step in (
            lambda: remove_project(shell),
            lambda: shell.run("remove-image", [docker, "image", "rm", "--force", IMAGE], 120),
            lambda: shell.run("prune-images", [docker, "image", "prune", "--force"], 300),
            lambda: shell.run("prune-cache", [docker, "builder", "prune", "--force"], 300),
        ):
            try:
                step()
            except Failure as error:  # the rest still goes
                say(f"teardown: {error}")
    daemon.stop()


@contextlib.contextmanager
def only_run(state: Path) -> Iterator[None]:
    """One run of this test at a time on a machine: they would share the daemon."""
    with (state / "lock").open("w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            say(f"waiting for another run of this test ({state / 'lock'})")
            fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="docker/e2e.py", description=__doc__.split("\n\n")[0].strip()
    )
    parser.add_argument(
        "--state",
        type=Path,
        default=DEFAULT_STATE,
        help=f"the engine's data root, the wheels and the logs (default {DEFAULT_STATE})",
    )
    parser.add_argument(
        "--keep-runs", type=Path, help="a directory to leave the checked run directories in"
    )
    options = parser.parse_args(argv)
    if sys.version_info[:2] != (3, 11):
        parser.error("needs Python 3.11, the stand-in's: its pip fetches the image's wheels")
    # SIGTERM ends the test as Ctrl-C does: through the teardown.
    signal.signal(signal.SIGTERM, terminate)
    try:
        options.state.mkdir(parents=True, exist_ok=True)
        with only_run(options.state):
            summary = end_to_end(options.state.resolve(), options.keep_runs)
    except Skip as why:
        say(f"skipped: {why}")
        return SKIP
    except Failure as why:
        say(f"failed: {why}")
        return 1
    except KeyboardInterrupt:
        say("interrupted; torn down")
        return 128 + signal.SIGINT
    except Terminated:
        say("terminated; torn down")
        return 128 + signal.SIGTERM
    say(f"passed in {summary}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
