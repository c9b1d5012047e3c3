"""Ctrl-C in every command line, at any moment: one line, exit status 130, never a traceback.

Python runs a signal's handler in the main thread only, when that thread next runs bytecode. A
main thread blocked on a lock (waiting for a worker thread's result, as an experiment's does)
can miss a Ctrl-C for as long as it waits, and measured under load it missed it altogether: an
interrupted experiment ran to the end and exited 0. A KeyboardInterrupt raised inside a
finaliser is dropped, with a traceback on stderr. So a Ctrl-C is also remembered the moment it
arrives: Python's C-level handler writes it to a wakeup pipe (`signal.set_wakeup_fd`), from any
thread, and a thread reading that pipe sets `INTERRUPTED`. Long loops check it between steps
(`check`), and `cli.app.run_app` exits 130 when it is set, whatever the command did with the
KeyboardInterrupt.

For `analytic`, SIGTERM (what `kill`, a container's stop and a cluster's scheduler send) is taken
as Ctrl-C: the command stops the same clean way, its run saved and its local farm's processes
stopped as for a Ctrl-C, and exits 143 (128 + SIGTERM). Left to Python's default, a SIGTERM
ended the process at once and orphaned the broker and workers of its local farm. A broker or
worker takes SIGTERM over itself once it serves (stop cleanly, exit 0); before that it holds
nothing, and Python's default ends it quietly, as the analytic stopping its farm early expects.

This module imports nothing but the standard library, so that the entry points (`launch`) can
take Ctrl-C over before the heavy imports (MuJoCo, Zenoh, pymoo: about a second) begin.
"""

import atexit
import contextlib
import importlib
import os
import signal
import sys
import threading
from types import FrameType
from typing import Any, NoReturn

INTERRUPTED_EXIT = 130  # 128 + SIGINT, as a shell reports a process Ctrl-C stopped
INTERRUPTED = threading.Event()
SIGNALS = (signal.SIGINT, signal.SIGTERM)  # both stop a command the same way

_installed = False
_write_end: int | None = None  # the wakeup pipe's, for uninstall
_received = signal.SIGINT  # the signal that stopped the command: its exit status says which


def _on_interrupt(signum: int, frame: FrameType | None) -> None:
    _remember(signum)
    raise KeyboardInterrupt


def _remember(signum: int) -> None:
    global _received
    if not INTERRUPTED.is_set():
        _received = signal.Signals(signum)
    INTERRUPTED.set()


def _watch(pipe: int) -> None:
    """Set INTERRUPTED the moment a SIGINT (or SIGTERM) reaches the process, whichever thread
    it reaches."""
    while True:
        try:
            received = os.read(pipe, 64)
        except OSError:
            return
        if not received:
            return
        for signum in SIGNALS:
            if signum in received:
                _remember(signum)


def _quiet_unraisable(unraisable: Any) -> None:  # sys.UnraisableHookArgs
    """A Ctrl-C that landed in a finaliser is remembered (INTERRUPTED), not printed as a
    traceback; anything else goes to Python's own hook."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        INTERRUPTED.set()
        return
    sys.__unraisablehook__(unraisable)


def install(signals: tuple[signal.Signals, ...] = (signal.SIGINT,)) -> None:
    """Take Ctrl-C (and the other `signals`, of SIGNALS) over (once; from the main thread, which
    alone may set signal handlers). Not a signal that is ignored: a shell starts background jobs
    deaf to SIGINT, and they are to stay so."""
    global _installed, _write_end
    if _installed or threading.current_thread() is not threading.main_thread():
        return
    taken = [signum for signum in signals if signal.getsignal(signum) is not signal.SIG_IGN]
    if not taken:
        return
    read, write = os.pipe()
    os.set_blocking(write, False)  # the C handler must never block on a full pipe
    signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    threading.Thread(target=_watch, args=(read,), name="interrupts", daemon=True).start()
    for signum in taken:
        signal.signal(signum, _on_interrupt)
    sys.unraisablehook = _quiet_unraisable
    _installed, _write_end = True, write


def uninstall() -> None:
    """Give Ctrl-C back to Python, as `install` found it: for a command run inside a process that
    goes on (the tests run the command lines in-process). The watching thread sees its pipe close
    and ends."""
    global _installed, _write_end, _received
    if not _installed or threading.current_thread() is not threading.main_thread():
        return
    if signal.getsignal(signal.SIGINT) is _on_interrupt:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGTERM) is _on_interrupt:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.set_wakeup_fd(-1)
    if _write_end is not None:
        os.close(_write_end)
    sys.unraisablehook = sys.__unraisablehook__
    INTERRUPTED.clear()
    _received = signal.SIGINT
    _installed, _write_end = False, None


def ours() -> bool:
    """Whether Ctrl-C (or SIGTERM) is still this module's to handle (a service's `start` takes
    both over to stop cleanly, and exits 0)."""
    return any(signal.getsignal(signum) is _on_interrupt for signum in SIGNALS)


def check() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed: for the points between a loop's steps
    (any thread), where stopping is safe."""
    if INTERRUPTED.is_set():
        raise KeyboardInterrupt


def stop(program: str, message: str = "interrupted") -> NoReturn:
    """Say `program: message` in one line on stderr, and exit at once: 130 after a Ctrl-C, 143
    after a SIGTERM (128 + the signal, as a shell reports it).

    Not by SystemExit: a KeyboardInterrupt that went through Python code a C extension ran
    (pybind11's and PyO3's exec: MuJoCo, Zenoh) marks the interpreter, which then ends itself
    by SIGINT instead of with the status given (measured: -2 instead of 130, about one Ctrl-C
    in four during the imports). What a clean exit would still do is done here: the command's
    `with` blocks have closed its files, farm and run by the time this is called."""
    print(f"{program}: {message}", file=sys.stderr, flush=True)
    if "logging" in sys.modules:  # not imported for this alone: stop() may end the imports
        sys.modules["logging"].shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(INTERRUPTED_EXIT if _received == signal.SIGINT else 128 + _received)


def launch(module: str, program: str, skip_teardown: bool = False, sigterm: bool = False) -> None:
    """The entry point of a command line: Ctrl-C handled first, then `module` imported and its
    `main()` run. A Ctrl-C during the imports stops here, in one line. `skip_teardown`: end
    with `exit_now`, for a command whose last messages are all received, none sent (a worker's
    last result, put as it stops, or a broker's last answers could still be on their way out
    of Zenoh when an `os._exit` ends its threads: a result lost at a worker's SIGTERM, seen
    once in the suite). `sigterm`: SIGTERM stops it as Ctrl-C does."""
    # `import mujoco` with MUJOCO_GL unset loads GLFW, whose import starts a Python child to
    # probe the library (60 ms of every start, measured); a Ctrl-C then cut the pipe it reads
    # and it printed a traceback of its own (2 runs of the Ctrl-C tests in 20). No command draws
    # through MuJoCo's default context: `analytic replay` makes its own (MUJOCO_GL if it names a
    # backend, else EGL). A user's MUJOCO_GL is kept.
    if not os.environ.get("MUJOCO_GL", "").strip():
        os.environ["MUJOCO_GL"] = "disable"
    install(SIGNALS if sigterm else (signal.SIGINT,))
    try:
        main = importlib.import_module(module).main
    except BaseException:
        # A C extension's initialiser that a Ctrl-C interrupted fails with its own error
        # (PyO3's: ImportError "initialization failed"): the Ctrl-C is the cause all the same.
        if INTERRUPTED.is_set():
            stop(program)
        raise
    if INTERRUPTED.is_set():  # pressed during the imports, and dropped by one of them
        stop(program)
    try:
        main()
    except KeyboardInterrupt:  # pressed as the command ended (its exit under way, say)
        stop(program)
    except SystemExit as done:  # how a command line ends, whatever its status
        status = done.code
    else:
        status = None
    finally:
        # The command is done: a Ctrl-C now comes too late to stop anything, and must not turn
        # its exit into a death by SIGINT (status -2, measured once `worker --version` took
        # 0.15 s instead of 1.6). A service's own handler, set in place of ours, stays.
        for signum in SIGNALS:
            if signal.getsignal(signum) is _on_interrupt:
                signal.signal(signum, signal.SIG_IGN)
    if skip_teardown:
        exit_now(status)
    sys.exit(status)


def exit_now(code: object = None) -> NoReturn:
    """End the process as `sys.exit(code)` would, without Python's teardown of every module
    and object: 0.3 s for a command that loaded pymoo, MuJoCo, Zenoh and matplotlib, a second
    on a busy machine, after a run's last line. What the teardown would still do for the
    command is done first: its threads that are not daemons are waited for, the functions
    registered with atexit run (logging's flush, the finalisers of temporary directories), and
    the standard streams are flushed. The command's `with` blocks have closed its files, farm
    and run by then (as for `stop`)."""
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()  # CPython's: what the interpreter itself runs at exit
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # sys.exit("message"): said on stderr, status 1
        print(code, file=sys.stderr)
        status = 1
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(status)
