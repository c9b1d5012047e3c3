"""The farm client's line to the farm: its one Zenoh session (which takes no message larger than a
wire message: docs/security.md), the study opened on it (the results subscriber, the liveliness
token the broker drops the study's queued jobs by, the model server that hands the workers the
study's feed-forward models in parts), the broker watched as it comes and goes, and whether the
client is waiting for it (`waiting`, told to `on_wait`)."""

import logging
import time
from collections.abc import Callable, Sequence

import zenoh

from gainfarm.broker.status import BrokerUnavailable, query_status
from gainfarm.edges.ask import ask
from gainfarm.edges.parts import reply_part
from gainfarm.edges.transport import SERVING_SESSION_BYTES, open_session, token_held
from gainfarm.schemas import keys
from gainfarm.schemas.security import TlsIdentity
from gainfarm.schemas.wire import BrokerStatus

log = logging.getLogger("gainfarm.analytic")

ANSWER_SECONDS = 10.0  # how long the broker has to answer a submission or a status query
BROKER_BACK = "broker-back"  # inbox markers
BROKER_GONE = "broker-gone"


class FarmUnavailable(ConnectionError):
    """No broker answered, or the study is already open elsewhere."""


class StudyLink:
    """One study's session with the farm. `on_result` is called on Zenoh's thread with every
    sample on the study's results key, `on_broker` with BROKER_BACK or BROKER_GONE."""

    def __init__(
        self,
        connect: Sequence[str],
        study: str,
        identity: TlsIdentity | None,
        models: dict[str, bytes],
    ):
        self.study = study
        self.models = models
        self.waiting: str | None = None  # why the client is waiting for the broker, if it is
        # Told each time `waiting` changes (a progress line says so); the reason, or None.
        self.on_wait: Callable[[str | None], None] = lambda why: None
        # Serves (the model key, in parts), takes results, asks the broker and fetches logs in
        # parts: no message it takes is larger than a wire message (docs/security.md).
        self.session = open_session(
            "client", connect=connect, identity=identity, max_message_bytes=SERVING_SESSION_BYTES
        )

    def open_study(
        self,
        connect: Sequence[str],
        on_result: Callable[[zenoh.Sample], None],
        on_broker: Callable[[str], None],
    ) -> None:
        token_key = keys.alive_study(self.study)
        self._subscriber = self.session.declare_subscriber(
            keys.study_results(self.study), on_result
        )
        # Asked after the subscriber: once answered, the router knows the subscriber (one link,
        # in order), before the token below lets any job be submitted.
        if token_held(self.session, token_key):
            raise FarmUnavailable(f"study {self.study!r} is already open in another process")
        # Declared whatever `models` holds now: an experiment adds a run's model to a client
        # it has made (analytic.experiments.runner.serving), and the workers must find it.
        self._model_server = self.session.declare_queryable(
            keys.model(self.study, "*"), self._on_model_query
        )
        self._token = self.session.liveliness().declare_token(token_key)

        def on_broker_token(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:  # a broker (re)started, with an empty queue
                on_broker(BROKER_BACK)
            else:
                on_broker(BROKER_GONE)

        self._broker_watch = self.session.liveliness().declare_subscriber(
            keys.ALIVE_BROKER, on_broker_token
        )
        self.await_study(", ".join(connect))

    def await_study(self, where: str) -> None:
        """The broker learns of the study from the token; wait until it has, so that a
        submission cannot overtake it."""
        give_up = time.monotonic() + ANSWER_SECONDS
        while time.monotonic() < give_up:
            try:
                status = query_status(self.session, timeout=1.0)
            except BrokerUnavailable:
                time.sleep(0.1)
                continue
            if any(study.name == self.study for study in status.studies):
                return
            time.sleep(0.02)
        raise FarmUnavailable(f"no gainfarm broker answered at {where}")

    def close(self) -> None:
        if not self.session.is_closed():
            self.session.close()  # undeclares the token: the broker drops what is still queued

    def status(self) -> BrokerStatus:
        return query_status(self.session)

    def wait(self, why: str, pending: int) -> None:
        """Say, once with the first reason until the broker answers again, that the client
        waits for it (with `pending` jobs)."""
        if self.waiting is None:
            log.warning("%s; waiting for it (%d jobs pending)", why, pending)
            self.waiting = why
            self.on_wait(why)

    def answers(self) -> bool:
        """Whether the broker answers now; clears `waiting` when it does again."""
        answered = ask(self.session, keys.STATUS, timeout=ANSWER_SECONDS) is not None
        if answered and self.waiting is not None:
            log.warning("the broker answers again")
            self.waiting = None
            self.on_wait(None)
        return answered

    def back(self) -> None:
        """A broker (re)started: whatever the client waited for is over."""
        if self.waiting is not None:
            self.waiting = None
            self.on_wait(None)

    def _on_model_query(self, query: zenoh.Query) -> None:
        wanted = keys.last_chunk(str(query.key_expr))
        if wanted in self.models:
            reply_part(query, self.models[wanted])
        else:
            query.reply_err(f"study {self.study} has no model {wanted[:64]}")
