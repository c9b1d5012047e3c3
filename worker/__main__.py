"""`worker` and `python -m worker`: Ctrl-C is taken over before worker.cli's imports begin."""

from gainfarm.cli.interrupts import launch


def main() -> None:
    launch("gainfarm.worker.cli", "worker")


if __name__ == "__main__":
    main()
