"""`broker` and `python -m broker`: Ctrl-C is taken over before broker.cli's imports begin."""

from gainfarm.cli.interrupts import launch


def main() -> None:
    launch("gainfarm.broker.cli", "broker")


if __name__ == "__main__":
    main()
