"""Runs ``pghm`` commands in forked child processes, for tests that need many real CLI runs.

Reads one JSON request per line on stdin, ``{"argv": [...], "cwd": "...", "env": {...}}``
(``env``: variables set in the child, optional), forks, and in
the child runs ``sys.exit(pghm.cli.main.main(argv))`` exactly as the ``pghm`` console script
does, with stdout and stderr sent to files; writes one JSON reply per line,
``{"code": exit status, "stdout": ..., "stderr": ...}``. An exception escaping ``main`` prints
its traceback and exits 1, as Python does.

Forking from a process that has already imported torch and pghm makes each run cost its own
work instead of ~3 s of imports. The server itself never runs a torch operation (so no
thread pool exists to be broken by the fork); each child starts its own.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import tempfile
import traceback

import pghm.cli.main as cli  # noqa: F401 - imported before forking, the point of the server

for module in ("data", "motion", "train", "export", "bench", "render", "synth"):
    __import__(f"pghm.cli.{module}")
import pghm.io.avatar  # noqa: E402,F401
import pghm.render  # noqa: E402,F401
import pghm.subject  # noqa: E402,F401
import pghm.train.fit  # noqa: E402,F401
import pghm.train.prior  # noqa: E402,F401


def run_child(argv: list[str], cwd: str, env: dict[str, str], out: int, err: int) -> None:
    """In the forked child: run the CLI and leave with its exit status (never returns)."""
    os.dup2(out, 1)
    os.dup2(err, 2)
    os.chdir(cwd)
    os.environ.update(env)
    # As in a terminal, Ctrl-C raises KeyboardInterrupt: a suite started as a background job of a
    # non-interactive shell inherits SIGINT ignored, which would make the Ctrl-C cases pass or
    # fail by how the suite was launched.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    code = 1
    try:
        code = cli.main(argv)
    except SystemExit as exit_request:
        code = exit_request.code if isinstance(exit_request.code, int) else (0 if exit_request.code is None else 1)
    except BaseException:  # noqa: BLE001 - report like the interpreter does
        traceback.print_exc()
        code = 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(int(code or 0))


def main() -> None:
    for line in sys.stdin:
        request = json.loads(line)
        with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
            pid = os.fork()
            if pid == 0:
                run_child(
                    request["argv"], request.get("cwd", os.getcwd()), request.get("env", {}), out.fileno(), err.fileno()
                )
            _, status = os.waitpid(pid, 0)
            replies = []
            for file in (out, err):
                file.seek(0)
                replies.append(file.read().decode("utf-8", errors="replace"))
        reply = {"code": os.waitstatus_to_exitcode(status), "stdout": replies[0], "stderr": replies[1]}
        sys.stdout.write(json.dumps(reply) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
