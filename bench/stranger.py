"""The attack of issue 47 on `analytic start`'s local farm: a process that finds the farm in the
process table, joins it as one more worker and forges every episode it is given (a forger,
tests/analytic/liar.py: made-up, self-consistent logs that flatter its candidates).

    python bench/stranger.py [--pop 16] [--generations 3] [--seed 7] [--duration 2] \
        [--workers 2] [--as nobody]

The same `analytic start --trajectory fourier --plants 0 --check-plants 0 --workers W` runs three
times: calm, with a forger of another user (`--as`: it imports as this user, then drops to that
user before it connects, as root can make it), and with a forger of this user. The attacker
watches /proc for the local farm's broker (`gainfarm.broker start --listen ENDPOINT`, which every
user of the host can read) and starts its forger on that endpoint at once. Printed for each: how
long the attacker took to find the farm, whether its forger joined (its Zenoh session opened),
the results the run refused ("did not start: refused" in its log), the front rows that are not
the calm run's (false rows), the workers provenance.csv names that the farm did not start, and
the command's exit status. Takes root for `--as`.
"""

import csv
import os
import pwd
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import click
from common import print_table

ROOT = Path(__file__).resolve().parents[1]  # where `python -m tests.analytic.liar` runs
# The forger imports everything it runs first (this user's interpreter may be out of the other
# user's reach), then becomes that user, then joins.
FORGER = """
import os, sys
import tests.analytic.liar as liar
uid, gid = int(sys.argv[3]), int(sys.argv[4])
if uid != os.getuid():
    os.setgroups([])
    os.setgid(gid)
    os.setuid(uid)
sys.argv = [sys.argv[0], sys.argv[1], sys.argv[2], "--forge"]
liar.main()
"""


def broker_endpoint(parent: int) -> str | None:
    """The --listen endpoint of a `gainfarm.broker start` child of `parent`, if one runs."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            words = (entry / "cmdline").read_bytes().split(b"\0")
            status = (entry / "status").read_text()
        except OSError:  # gone meanwhile
            continue
        if b"gainfarm.broker" in words and b"--listen" in words and f"PPid:\t{parent}\n" in status:
            return words[words.index(b"--listen") + 1].decode()
    return None


class Attacker(threading.Thread):
    """Finds the farm of `analytic` and starts a forger on it as `user`."""

    def __init__(self, analytic: subprocess.Popen, user: pwd.struct_passwd, log: Path):
        super().__init__(daemon=True)
        self.analytic, self.user, self.log = analytic, user, log
        self.found_after: float | None = None
        self.forger: subprocess.Popen | None = None

    def run(self) -> None:
        began = time.monotonic()
        while self.analytic.poll() is None:
            endpoint = broker_endpoint(self.analytic.pid)
            if endpoint is not None:
                self.found_after = time.monotonic() - began
                ids = [str(self.user.pw_uid), str(self.user.pw_gid)]
                command = [sys.executable, "-c", FORGER, endpoint, "forger", *ids]
                with self.log.open("w") as out:
                    self.forger = subprocess.Popen(
                        command, cwd=ROOT, stdin=subprocess.DEVNULL, stderr=out, stdout=out
                    )
                return
            time.sleep(0.01)

    def joined(self) -> bool:
        """Whether the forger's session opened: it failed at once with the farm's endpoint if
        not (a worker that cannot connect says so and exits)."""
        return "cannot open a Zenoh" not in self.log.read_text()

    def stop(self) -> None:
        if self.forger is not None:
            self.forger.terminate()
            try:
                self.forger.wait(15)
            except subprocess.TimeoutExpired:
                self.forger.kill()
                self.forger.wait()


def front_rows(out: Path) -> list[tuple[str, ...]]:
    with (out / "front.csv").open() as rows:
        return [tuple(row) for row in csv.reader(rows)][1:]


def workers_named(out: Path) -> set[str]:
    with (out / "provenance.csv").open() as rows:
        return {row["worker"] for row in csv.DictReader(rows)}


def run(arguments: list[str], out: Path, user: pwd.struct_passwd | None) -> dict:
    command = [sys.executable, "-m", "gainfarm.analytic", "start", *arguments, "--out", str(out)]
    log = out.with_suffix(".log")
    with open(log, "w") as said:
        analytic = subprocess.Popen(command, stdin=subprocess.DEVNULL, stderr=said, stdout=said)
    attacker = Attacker(analytic, user, out.with_suffix(".forger.log")) if user else None
    if attacker is not None:
        attacker.start()
    try:
        status = analytic.wait()
    finally:
        if attacker is not None:
            attacker.join()
            attacker.stop()
    text = log.read_text()
    return {
        "status": status,
        "found": attacker.found_after if attacker else None,
        "joined": attacker.joined() if attacker else None,
        "refused": text.count("did not start: refused"),
        "rows": front_rows(out) if status == 0 else [],
        "workers": workers_named(out) if status == 0 else set(),
    }


@click.command()
@click.option("--pop", default=16, show_default=True)
@click.option("--generations", default=3, show_default=True)
@click.option("--seed", default=7, show_default=True)
@click.option("--duration", default=2.0, show_default=True)
@click.option("--workers", default=2, show_default=True)
@click.option("--as", "other", default="nobody", show_default=True, help="the other user")
def main(pop: int, generations: int, seed: int, duration: float, workers: int, other: str) -> None:
    arguments = [
        *("--pop", str(pop), "--generations", str(generations), "--seed", str(seed)),
        *("--trajectory", "fourier", "--duration", str(duration)),
        *("--plants", "0", "--check-plants", "0", "--workers", str(workers)),
    ]
    print("analytic start", " ".join(arguments))
    me, stranger = pwd.getpwuid(os.getuid()), pwd.getpwnam(other)
    with tempfile.TemporaryDirectory() as scratch:
        calm = run(arguments, Path(scratch) / "calm", None)
        found = {
            f"forger as {other}": run(arguments, Path(scratch) / "other", stranger),
            f"forger as {me.pw_name}": run(arguments, Path(scratch) / "same", me),
        }
    rows = [["calm", "", "", "", str(len(calm["rows"])), "", "", str(calm["status"])]]
    for name, result in found.items():
        false = [row for row in result["rows"] if row not in calm["rows"]]
        strangers = sorted(w for w in result["workers"] if not w.startswith("local-"))
        rows.append(
            [
                name,
                f"{result['found']:.2f}" if result["found"] is not None else "never",
                "yes" if result["joined"] else "no",
                str(result["refused"]),
                str(len(result["rows"])),
                str(len(false)),
                ",".join(strangers) or "none",
                str(result["status"]),
            ]
        )
    headers = [
        "run",
        "found (s)",
        "joined",
        "refused",
        "front rows",
        "false rows",
        "strangers in provenance",
        "exit",
    ]
    print_table(headers, "lrlrrrlr", rows)


if __name__ == "__main__":
    main()
