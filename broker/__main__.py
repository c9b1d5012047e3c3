"""`broker` and `python -m broker`: Ctrl-C is taken over before broker.cli's imports begin."""

from cli.interrupts import launch


def main() -> None:
    launch("broker.cli", "broker")


if __name__ == "__main__":
    main()
