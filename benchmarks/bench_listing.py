"""The listing commands cost little more than starting Python: they import only what they list.

`slamfront recipes`, `layout`, `datasets` and `datasets path` read a few files; each is
timed as a whole child process (interpreter start included) against `python -c pass`
in the same venv, interleaved round by round (A B C ... A B C ...; the machine is
shared, so only ratios against the peer measured beside it mean something). The median
of the rounds is kept. `slamfront plugins` is measured too, with the heavy libraries it
imports (it imports every plugin module; a plugin's OpenCV, Open3D, GTSAM or numba should
load only when the plugin is built).

Bytecode is written (a user's machine caches it; the first, warm-up round pays for it).

Run: .venv/bin/python benchmarks/bench_listing.py [--rounds 15]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from importlib.metadata import version
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import publish, table  # noqa: E402

BIN = Path(sys.executable).parent
COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "slamfront recipes": [str(BIN / "slamfront"), "recipes"],
    "slamfront layout": [str(BIN / "slamfront"), "layout"],
    "slamfront datasets": [str(BIN / "slamfront"), "datasets"],
    "slamfront datasets path": [str(BIN / "slamfront"), "datasets", "path"],
    "slamfront plugins": [str(BIN / "slamfront"), "plugins"],
}
BUDGET = 3.0
"""A listing may cost at most this many bare interpreter starts."""
HEAVY = ("cv2", "open3d", "gtsam", "numba", "scipy", "matplotlib", "mcap", "torch", "faiss")


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["COLUMNS"] = "200"
    return env


def wall(command: list[str]) -> tuple[float, float]:
    """(wall seconds, CPU seconds: user + system) of one run of ``command`` as a child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env())
    elapsed = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return elapsed, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def heavy_imports(args: list[str]) -> list[str]:
    """The heavy top-level packages a `slamfront ARGS` process has imported when it exits."""
    probe = (
        "import sys, atexit, io, contextlib\n"
        # loaded, that is: a module slamfront.lazy holds for later is not
        f"atexit.register(lambda: print(' '.join(m for m in {HEAVY!r} if type(sys.modules.get(m)).__name__ == 'module'), "
        "file=sys.__stderr__))\n"
        "from slamfront.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    main({args!r})\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=_env(), check=True)
    return done.stderr.split()


def machine() -> str:
    """CPU model and the versions the numbers depend on, for the table's reader."""
    model = platform.processor() or "?"
    try:
        model = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                     if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    libraries = ", ".join(f"{name} {version(name)}" for name in ("numpy", "pydantic", "PyYAML", "pluggy"))
    return f"CPU {model} ({os.cpu_count()} cores, shared); Python {platform.python_version()}; {libraries}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    args = parser.parse_args()
    for command in COMMANDS.values():  # warm-up: bytecode, page cache
        wall(command)
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in COMMANDS}
    for _ in range(args.rounds):
        for name, command in COMMANDS.items():
            times[name].append(wall(command))
    bare_wall = statistics.median(w for w, _ in times["python -c pass"])
    bare_cpu = statistics.median(c for _, c in times["python -c pass"])
    rows, over = [], []
    for name, measured in times.items():
        wall_ratio = statistics.median(w for w, _ in measured) / bare_wall
        cpu_ratio = statistics.median(c for _, c in measured) / bare_cpu
        listing = name not in ("python -c pass", "slamfront plugins")
        if listing and min(wall_ratio, cpu_ratio) > BUDGET:
            over.append(name)
        heavy = ", ".join(heavy_imports(COMMANDS[name][1:])) if name.startswith("slamfront") else ""
        rows.append([name, statistics.median(w for w, _ in measured) * 1000, wall_ratio,
                     statistics.median(c for _, c in measured) * 1000, cpu_ratio,
                     f"<= {BUDGET:g}" if listing else "-", heavy or "none"])
    load = os.getloadavg()[0]
    body = (
        f"{machine()}; load average {load:.1f} when the rounds ended. {args.rounds} interleaved rounds after a "
        "warm-up round; whole processes, medians. The CPU time (user + system of the child) depends little on "
        "the load of a shared machine; the wall time does.\n\n"
        + table(["command", "wall (ms)", "x python -c pass", "CPU (ms)", "x python -c pass (CPU)", "budget",
                 "heavy libraries loaded"], rows)
        + "\n\n`slamfront plugins` lists every plugin with every parameter, so it imports every plugin module "
        "(NumPy and pydantic); OpenCV, Open3D, GTSAM and SciPy load when a plugin computes (`slamfront.lazy`). "
        "A library listed here is loaded by an installed third-party plugin module (the example plugin imports "
        "OpenCV at the top).\n"
    )
    publish("listing", "Listing commands against a bare interpreter start", body)
    if over:
        print(f"over budget ({BUDGET:g}x): {', '.join(over)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
