"""The key-expression space: every Zenoh key the farm uses is spelled here and nowhere else.

The broker's services carry the name they act for in their last chunk (the study a submission is
for, the worker asking for a lease), so that the secure profile's access policy can let each
participant use only its own (schemas/security.py); the broker checks that the message says the
same name as its key.
"""

ROOT = "gainfarm"

STATUS = f"{ROOT}/broker/status"  # queryable: (nothing) → BrokerStatus
SUBMIT_ANY = f"{ROOT}/broker/submit/*"
LEASE_ANY = f"{ROOT}/broker/lease/*"
CONFIRM_ANY = f"{ROOT}/broker/confirm/*"

ALL_RESULTS = f"{ROOT}/study/*/result/*"
ALL_MODELS = f"{ROOT}/study/*/model/*"
ALIVE_WORKERS = f"{ROOT}/alive/worker/*"
ALIVE_STUDIES = f"{ROOT}/alive/study/*"
ALIVE_BROKER = f"{ROOT}/alive/broker"  # appears anew when a broker (re)starts: its queue is empty


def submit(study: str) -> str:
    """Queryable: Submission → SubmitReply, for the study in the last chunk."""
    return f"{ROOT}/broker/submit/{study}"


def lease(worker: str) -> str:
    """Queryable: LeaseRequest → LeaseReply; a worker hands in its results and asks for more
    work (held while there is none)."""
    return f"{ROOT}/broker/lease/{worker}"


def confirm(study: str) -> str:
    """Queryable: ConfirmRequest → ConfirmReply; which results of the study the broker accepted."""
    return f"{ROOT}/broker/confirm/{study}"


def result(study: str, job_id: str) -> str:
    """Where a worker puts a job's Result (attachment) and episode log (payload)."""
    return f"{ROOT}/study/{study}/result/{job_id}"


def model(study: str, digest: str) -> str:
    """Queryable: (nothing) → the bytes of the study's feed-forward model with that SHA-256,
    served by the analytic process that owns the study, fetched once by each worker."""
    return f"{ROOT}/study/{study}/model/{digest}"


def log(study: str, worker: str, digest: str) -> str:
    """Queryable: (nothing) → the episode log with that SHA-256 that `worker` made for a job of
    `study` and keeps (a job without `keep_log`); served by the worker itself."""
    return f"{ROOT}/study/{study}/log/{worker}/{digest}"


def worker_logs(worker: str) -> str:
    """Every log key a worker serves: what it declares, and what its access policy allows."""
    return log("*", worker, "*")


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
