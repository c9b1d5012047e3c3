"""Workers that hold the farm up without lying, run as `python -m tests.rogue KIND ENDPOINT NAME`
by the liveness tests and bench/liveness.py. Each holds its liveliness token like any worker.

- `hoarder`: asks for a whole batch (MAX_BATCH) and runs none of it, never hands anything in, and
  asks for more again at once, over and over.
- `holder`: the same, but asks again only after `--hold` seconds (default: never): it sits on
  the batch it was given.
- `silent`: runs its jobs and hands their results in to the broker, but never sends them to
  their study, nor keeps their logs to be fetched.
"""

import signal
import sys
import threading

from gainfarm.schemas.wire import MAX_BATCH, Verdict
from gainfarm.worker.service import CobotWorker, HandIn

RETRY_SECONDS = 1.0


class Hoarder(CobotWorker):
    def hoard(self, stop: threading.Event, hold: float | None) -> None:
        """Take batches and sit on each for `hold` seconds (None: for good)."""
        while not stop.is_set():
            reply = self._ask_for_work(MAX_BATCH, [])
            if reply is None:
                stop.wait(RETRY_SECONDS)
            elif reply.leases:
                self.jobs_done += len(reply.leases)  # taken, not done: what it hoarded
                if hold is None:
                    stop.wait()
                else:
                    stop.wait(hold)


class SilentHolder(CobotWorker):
    def _send(self, ran: list[HandIn], verdicts: list[Verdict]) -> None:
        """The broker took the results: say nothing of them to anyone."""
        self.jobs_done += len(ran)


def main() -> None:
    kind, endpoint, name = sys.argv[1:4]
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    if kind == "silent":
        with SilentHolder([endpoint], name) as silent:
            silent.serve(stop)
        return
    hold = 0.0 if kind == "hoarder" else None
    if "--hold" in sys.argv:
        hold = float(sys.argv[sys.argv.index("--hold") + 1])
    with Hoarder([endpoint], name) as hoarder:
        hoarder.hoard(stop, hold)


if __name__ == "__main__":
    main()
