"""The sim-cobot on the wire: connect, hold a liveliness token, ask for work when free, return
each result with its episode log. One process is one cobot.
"""

import logging
import threading
from collections.abc import Sequence

import zenoh

from schemas import keys
from schemas.security import TlsIdentity
from schemas.transport import open_session, token_held
from schemas.wire import LEASE_HOLD_SECONDS, BadMessage, LeaseReply, LeaseRequest, decode
from worker.job import execute

log = logging.getLogger("gainfarm.worker")

ANSWER_MARGIN = 5.0  # s beyond the broker's longest hold before a lease request counts as lost
RETRY_SECONDS = 1.0  # pause after a broker that did not answer or answered with an error
ZENOH_TIMEOUT = "Timeout"  # the payload of the error reply Zenoh makes when a query times out


class NameTaken(RuntimeError):
    pass


class CobotWorker:
    def __init__(self, connect: Sequence[str], name: str, identity: TlsIdentity | None = None):
        request = LeaseRequest(worker=name)  # validates the name: it becomes a key chunk
        self.name = request.worker
        self._request = request.to_bytes()
        self.jobs_done = 0
        self.session = open_session("client", connect=connect, identity=identity)
        try:
            if token_held(self.session, keys.alive_worker(name)):
                raise NameTaken(f"a worker named {name!r} is already connected to this farm")
            self._token = self.session.liveliness().declare_token(keys.alive_worker(name))
        except BaseException:
            self.session.close()
            raise

    def __enter__(self) -> "CobotWorker":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if not self.session.is_closed():
            self._token.undeclare()
            self.session.close()

    def serve(self, stop: threading.Event, max_jobs: int | None = None) -> int:
        """Serve until `stop` is set (a job in progress is finished and returned first)."""
        while not stop.is_set() and (max_jobs is None or self.jobs_done < max_jobs):
            reply = self._ask_for_work()
            if reply is None:
                stop.wait(RETRY_SECONDS)
            elif reply.lease is not None:
                result, content = execute(reply.lease, self.name)
                self.session.put(
                    keys.result(result.study, result.job_id),
                    content,
                    attachment=result.to_bytes(),
                    congestion_control=zenoh.CongestionControl.BLOCK,
                )
                self.jobs_done += 1
                log.info(
                    "%s/%s: %s in %.3f s",
                    result.study,
                    result.job_id,
                    result.status.value,
                    result.timings.simulate_s + result.timings.encode_s,
                )
        return self.jobs_done

    def _ask_for_work(self) -> LeaseReply | None:
        """The broker's answer, or None if there was no usable one."""
        replies = self.session.get(
            keys.LEASE, payload=self._request, timeout=LEASE_HOLD_SECONDS + ANSWER_MARGIN
        )
        for reply in replies:
            if reply.ok is None:
                reason = _text(reply.err.payload)
                if reason == ZENOH_TIMEOUT:  # Zenoh's own error reply: nobody answered in time
                    break
                log.warning("the broker refused a lease request: %s", reason)
                return None
            try:
                return decode(LeaseReply, reply.ok.payload.to_bytes())
            except BadMessage as error:
                log.warning("ignored a bad lease reply: %s", error)
                return None
        log.warning("no broker answered on %s; asking again", keys.LEASE)
        return None


def _text(payload: zenoh.ZBytes) -> str:
    return payload.to_bytes().decode(errors="replace")
