"""``python3 -c CODE ARGS...`` without paying Python's start-up each time: a process that has imported what the
commands need forks a child for each run, and the child runs ``CODE`` as ``python3 -c`` would.

For the tests that start hundreds of short processes (the bad-input corpus, the import check of every module), where
starting Python and importing numpy is most of the cost. The child runs in its own folder and environment, its
standard input ``/dev/null``, its output and errors into files, with the default SIGINT handler, and ends as a
Python process ends: ``SystemExit`` gives the status, an uncaught exception its traceback and status 1, ``atexit``
handlers run and the streams are flushed. What the parent imported (``preload``) is already in ``sys.modules``: pick
only packages whose import the run does not test.
"""

from __future__ import annotations

import json
import queue
import subprocess
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

# The forking process: it imports the modules named on its command line, then reads one job a line (JSON: code, argv,
# cwd, env, the output files, the timeout), forks a child that runs the job, and answers with the child's exit status
# (null when it ran over the timeout and was killed).
_FORKER = """
import atexit, importlib, json, os, signal, sys, time, traceback
for name in sys.argv[1:]:
    importlib.import_module(name)
replies = sys.stdout
for line in sys.stdin:
    job = json.loads(line)
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            os.chdir(job["cwd"])
            os.environ.clear()
            os.environ.update(job["env"])
            signal.signal(signal.SIGINT, signal.default_int_handler)
            for fd, opened in ((0, os.open(os.devnull, os.O_RDONLY)),
                               (1, os.open(job["stdout"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)),
                               (2, os.open(job["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644))):
                os.dup2(opened, fd)
                os.close(opened)
            sys.argv = ["-c", *job["argv"]]
            try:
                exec(compile(job["code"], "<string>", "exec"), {"__name__": "__main__"})
                code = 0
            except SystemExit as exc:
                if exc.code is None or isinstance(exc.code, int):
                    code = exc.code or 0
                else:
                    print(exc.code, file=sys.stderr)
            except BaseException:
                traceback.print_exc()
            atexit._run_exitfuncs()
        finally:
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except Exception:
                    pass
            os._exit(code)
    deadline = time.monotonic() + job["timeout"]
    while (done := os.waitpid(pid, os.WNOHANG))[0] == 0 and time.monotonic() < deadline:
        time.sleep(0.005)
    if done[0] == 0:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        status = None
    else:
        status = os.waitstatus_to_exitcode(done[1])
    replies.write(json.dumps(status) + "\\n")
    replies.flush()
"""


class Forker:
    """One forking process that has imported ``preload`` (see the module's docstring)."""

    def __init__(self, preload: Sequence[str], env: dict[str, str] | None = None) -> None:
        self.process = subprocess.Popen([sys.executable, "-c", _FORKER, *preload], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True, env=env)  # fmt: skip

    def run(self, code: str, argv: Sequence[str], *, cwd: Path, env: dict[str, str], streams: Path,
            timeout: float) -> tuple[int | None, str, str]:  # fmt: skip
        """Run ``python3 -c code *argv`` in ``cwd`` with ``env``: (exit status or None after ``timeout`` seconds,
        stdout, stderr), the two kept in ``streams`` with the suffixes ``.out`` and ``.err``."""
        out, err = streams.with_suffix(".out"), streams.with_suffix(".err")
        job = {"code": code, "argv": list(argv), "cwd": str(cwd), "env": env, "stdout": str(out),
               "stderr": str(err), "timeout": timeout}  # fmt: skip
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(json.dumps(job) + "\n")
        self.process.stdin.flush()
        reply = self.process.stdout.readline()
        assert reply, f"the forking process ended (exit status {self.process.wait()})"
        return json.loads(reply), out.read_text(errors="replace"), err.read_text(errors="replace")

    def close(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.close()
        self.process.wait(timeout=60)


@contextmanager
def forkers(count: int, preload: Sequence[str], env: dict[str, str] | None = None) -> Iterator[queue.Queue]:
    """``count`` forking processes in a queue, for as many threads: take one (``get``), run, put it back."""
    started = [Forker(preload, env) for _ in range(count)]
    pool: queue.Queue = queue.Queue()
    for forker in started:
        pool.put(forker)
    try:
        yield pool
    finally:
        for forker in started:
            forker.close()
