"""The key-expression space: every Zenoh key the farm uses is spelled here and nowhere else."""

ROOT = "gainfarm"

SUBMIT = f"{ROOT}/broker/submit"  # queryable: Submission → SubmitReply
LEASE = f"{ROOT}/broker/lease"  # queryable: LeaseRequest → LeaseReply, held while there is no work
STATUS = f"{ROOT}/broker/status"  # queryable: (nothing) → BrokerStatus

ALL_RESULTS = f"{ROOT}/study/*/result/*"
ALIVE_WORKERS = f"{ROOT}/alive/worker/*"
ALIVE_STUDIES = f"{ROOT}/alive/study/*"
ALIVE_BROKER = f"{ROOT}/alive/broker"  # appears anew when a broker (re)starts: its queue is empty


def result(study: str, job_id: str) -> str:
    """Where a worker puts a job's Result (attachment) and episode log (payload)."""
    return f"{ROOT}/study/{study}/result/{job_id}"


def study_results(study: str) -> str:
    return f"{ROOT}/study/{study}/result/*"


def alive_worker(name: str) -> str:
    """A worker's liveliness token: it vanishes the moment the worker's session does."""
    return f"{ROOT}/alive/worker/{name}"


def alive_study(study: str) -> str:
    """An analytic process's liveliness token for its study: its jobs live as long as it does."""
    return f"{ROOT}/alive/study/{study}"


def last_chunk(key: str) -> str:
    return key.rsplit("/", 1)[-1]
