"""`worker` and `python -m worker`: Ctrl-C is taken over before worker.cli's imports begin."""

from cli.interrupts import launch


def main() -> None:
    launch("worker.cli", "worker")


if __name__ == "__main__":
    main()
