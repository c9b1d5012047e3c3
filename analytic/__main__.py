"""`analytic` and `python -m analytic`: Ctrl-C and SIGTERM are taken over before analytic.cli's
imports begin (a SIGTERM stops a run as Ctrl-C does, its local farm with it)."""

from gainfarm.cli.interrupts import launch


def main() -> None:
    launch("gainfarm.analytic.cli", "analytic", skip_teardown=True, sigterm=True)


if __name__ == "__main__":
    main()
