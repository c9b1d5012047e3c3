"""Which workers get a study's jobs: none for those the client distrusts (caught claiming scores
their logs do not have), leaves out (their results never came), or refuses (strangers to the
local farm it started, `own_workers`), and none that need a plug-in (an arm, a trajectory kind,
an objective) for a worker that refused a job lacking it; and how many connected workers are
left to run them."""

import logging
from collections.abc import Callable, Collection

from gainfarm import plugins
from gainfarm.broker.status import BrokerUnavailable
from gainfarm.plugins import PluginError
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.wire import BadMessage, BrokerStatus

log = logging.getLogger("gainfarm.analytic")


class Workers:
    """The workers a study's client has seen, and whom it gives none of its jobs. `status` asks
    the broker who is connected now."""

    def __init__(
        self, status: Callable[[], BrokerStatus], own_workers: Collection[str] | None = None
    ):
        self.status = status
        self.own_workers = None if own_workers is None else frozenset(own_workers)
        self.distrusted: set[str] = set()
        self.unheard_from: set[str] = set()
        self.strangers: set[str] = set()
        # Who refused jobs needing what (a trajectory kind and objectives: `needs`): a worker
        # that lacks a plug-in gets no more jobs that need it.
        self.refused_by: dict[tuple[str, ...], set[str]] = {}

    def barred(self) -> set[str]:
        """The workers given none of this study's jobs."""
        return self.distrusted | self.unheard_from | self.strangers

    def refusers(self, spec: EpisodeSpec) -> set[str]:
        """The workers that refused a job needing what `spec` needs."""
        return self.refused_by.get(needs(spec), set())

    def able(self, status: BrokerStatus, barred: set[str]) -> int:
        """How many workers connected now are not `barred` (and are this client's own, if it
        has `own_workers`): by name where the status lists them all, else by count."""
        names = {worker.name for worker in status.workers}
        if len(names) == status.worker_count:
            if self.own_workers is not None:
                names &= self.own_workers
            return len(names - barred)
        return max(status.worker_count - len(barred), 0)

    def trusted_capacity(self) -> int:
        """The workers connected now that may still run this study's jobs: neither distrusted
        nor left out (by name where the status lists them all, else by count). A broker that
        does not answer is no verdict: taken as one (the run goes on, and waits for it)."""
        try:
            status = self.status()
        except (BrokerUnavailable, BadMessage):
            return 1
        return self.able(status, self.barred())

    def stranger(self, worker: str) -> bool:
        """Whether `worker` is not one this client's local farm started."""
        return self.own_workers is not None and worker not in self.own_workers

    def turn_away(self, worker: str) -> None:
        """Give a stranger none of the study's jobs (said once per worker)."""
        if worker not in self.strangers:
            self.strangers.add(worker)
            why = "which this local farm did not start: refused"
            log.warning("result from worker %s, %s", worker, why)

    def leave_out(self, worker: str) -> None:
        """Give `worker`, whose result never came, none of this study's jobs from now on: unless
        it is the last worker left to run them (its result may only have been late)."""
        if worker in self.unheard_from:
            return
        try:
            connected = self.status().worker_count
        except (BrokerUnavailable, BadMessage):
            return
        if connected > len(self.barred() | {worker}):
            self.unheard_from.add(worker)
            log.warning("%s gets no more of this study's jobs: its results do not come", worker)

    def refused(self, spec: EpisodeSpec, worker: str) -> None:
        """`worker` refused a job needing what `spec` needs: it gets no more such jobs."""
        self.refused_by.setdefault(needs(spec), set()).add(worker)

    def others_for(self, spec: EpisodeSpec, avoid: Collection[str]) -> bool:
        """Whether a worker connected now may run the job: not avoided by it, nor barred. A
        broker that does not answer is no verdict: taken as yes (the job waits for it)."""
        try:
            status = self.status()
        except (BrokerUnavailable, BadMessage):
            return True
        return self.able(status, {*self.barred(), *avoid, *self.refusers(spec)}) > 0


def needs(spec: EpisodeSpec) -> tuple[str, ...]:
    """The plug-ins a job needs by name: its robot (its plant's), its trajectory kind, then its
    objectives. A worker that refused a job of one arm may still run another's."""
    return (spec.plant.robot, spec.trajectory.kind, *spec.objectives)


def lacked_here(spec: EpisodeSpec) -> bool:
    """Whether this process lacks a plug-in the job needs (cannot load it either)."""
    try:
        plugins.load(plugins.ROBOTS, spec.plant.robot)
        plugins.load(plugins.TRAJECTORIES, spec.trajectory.kind)
        plugins.load_plugins(plugins.OBJECTIVES, spec.objectives)
    except PluginError:
        return True
    return False
