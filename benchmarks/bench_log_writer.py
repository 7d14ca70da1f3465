"""What the log's writing thread takes off a run's own thread.

Copies every message of a run's log (already serialised) into a new log, with the MCAP
writer on its second thread as runs use it, and with the same jobs run inline on the
calling thread (how the writer worked before the thread), interleaved: the calling
thread's CPU time is what a run's own thread pays for the MCAP writer (building chunks,
zstd, CRCs, the file's hash and writes); the process's CPU time shows whether the thread
costs extra. Serialising the messages (JSON, protobuf) is not in it: it stays on the
run's thread either way.

Run: .venv/bin/python benchmarks/bench_log_writer.py LOG [LOG ...] [--repeats 3]
(e.g. the ``run.mcap`` of ``slamfront run nordland_hsl`` and of ``nordland_seqslam``).
Writes results/log_writer.md.
"""

from __future__ import annotations

import argparse
import contextlib
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

from slamfront.mcaplog import writer as log_writer  # noqa: E402
from slamfront.mcaplog.reader import read_messages  # noqa: E402


def _process_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


@contextlib.contextmanager
def _inline() -> Iterator[None]:
    """The writer's jobs run on the calling thread, one by one, as before the thread."""
    submit = log_writer._Background.submit

    def run_here(self: log_writer._Background, job: Callable[[], None]) -> None:
        job()

    log_writer._Background.submit = run_here  # type: ignore[method-assign]
    try:
        yield
    finally:
        log_writer._Background.submit = submit  # type: ignore[method-assign]


def _copy(messages: list, out: Path) -> tuple[float, float, float]:
    """Wall, calling-thread CPU and process CPU seconds of writing ``messages`` to ``out``."""
    wall, thread, process = time.perf_counter(), time.thread_time(), _process_cpu()
    with log_writer.RunLogWriter(out, sync_seconds=5.0) as log:
        for message in messages:
            log.copy(message)
    return time.perf_counter() - wall, time.thread_time() - thread, _process_cpu() - process


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("logs", nargs="+", type=Path)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "copy.mcap"
        for path in args.logs:
            messages = list(read_messages(path))
            seconds: dict[str, list[tuple[float, float, float]]] = {"thread": [], "inline": []}
            for _ in range(args.repeats):  # interleaved: the load changes between rounds
                seconds["thread"].append(_copy(messages, out))
                with _inline():
                    seconds["inline"].append(_copy(messages, out))
            median = {mode: [statistics.median(s[i] for s in values) for i in range(3)]
                      for mode, values in seconds.items()}
            rows.append([path.parent.name or str(path), len(messages), f"{path.stat().st_size / 1e6:.1f}",
                         median["inline"][1], median["thread"][1], median["inline"][2], median["thread"][2],
                         median["inline"][0], median["thread"][0]])
    load = Path("/proc/loadavg").read_text().split()[0] if Path("/proc/loadavg").exists() else "?"
    body = (
        f"Each log's messages copied into a new log, {args.repeats} rounds, with and without the writing "
        f"thread interleaved; medians. Machine load (1-min average) {load} at the end, 2 cores shared with "
        "other jobs: wall seconds depend on the load; the calling thread's CPU is what a run's own thread pays.\n\n"
        + table(["log", "messages", "MB", "own thread CPU s, inline", "own thread CPU s, thread",
                 "process CPU s, inline", "process CPU s, thread", "wall s, inline", "wall s, thread"], rows)
    )
    publish("log_writer", "The log's writing thread", body)


if __name__ == "__main__":
    main()
