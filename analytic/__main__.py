"""`analytic` and `python -m analytic`: Ctrl-C is taken over before analytic.cli's imports begin."""

from gainfarm.cli.interrupts import launch


def main() -> None:
    launch("gainfarm.analytic.cli", "analytic", skip_teardown=True)


if __name__ == "__main__":
    main()
