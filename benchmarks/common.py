"""Helpers shared by the benchmark scripts: timing, peak memory, writing result tables.

Every results file :func:`publish` writes ends with the machine it was measured on (CPU
model, cores, SIMD extensions, Python and library versions): a timing means nothing
without it, and these machines differ (some have AVX-512, some do not).
"""

from __future__ import annotations

import os
import platform
import re
import resource
import subprocess
import time
from collections.abc import Callable, Sequence
from importlib import metadata
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def best_of(repeats: int, work: Callable[[], object]) -> float:
    """The fastest of ``repeats`` wall-clock timings of ``work()`` (seconds)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return min(times)


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, MB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    def cell(value: object) -> str:
        return f"{value:.4g}" if isinstance(value, float) else str(value)

    lines = ["| " + " | ".join(headers) + " |", "|" + " --- |" * len(headers)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


LIBRARIES = ("numpy", "opencv-contrib-python-headless", "gtsam", "numba", "open3d")
"""Libraries whose versions every results file records (those installed)."""


def cpu_model() -> str:
    """The CPU's model name, with its family and model numbers on Linux (a virtual machine may
    call every generation "AMD EPYC"); macOS: sysctl; else what ``platform`` knows."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        info = ""
    found = {key: re.search(rf"^{key}\s*:\s*(.+)$", info, re.MULTILINE) for key in ("model name", "cpu family", "model")}
    if found["model name"]:
        numbers = f" (family {found['cpu family'].group(1)}, model {found['model'].group(1)})" if found["model"] else ""
        return found["model name"].group(1).strip() + numbers
    try:
        return subprocess.run(["sysctl", "-n", "machdep.cpu.brand_string"], capture_output=True, text=True,
                              check=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return platform.processor() or platform.machine()


def simd_extensions() -> str:
    """The vector instruction sets the CPU reports that compiled kernels use (Linux only)."""
    try:
        flags = set(re.search(r"^flags\s*:(.*)$", Path("/proc/cpuinfo").read_text(), re.MULTILINE).group(1).split())
    except (OSError, AttributeError):
        return ""
    wanted = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl", "avx512_vnni")
    return " ".join(f for f in wanted if f in flags)


def machine(libraries: Sequence[str] = LIBRARIES) -> str:
    """One line naming the machine: CPU model, cores, SIMD, OS, Python, library versions."""
    versions = []
    for name in libraries:
        try:
            versions.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            continue
    simd = simd_extensions()
    return (
        f"Machine: {cpu_model()}, {os.cpu_count()} logical cores{f' ({simd})' if simd else ''}, "
        f"{platform.system()} {platform.machine()}, Python {platform.python_version()}; " + ", ".join(versions) + "."
    )


def publish(name: str, title: str, body: str, libraries: Sequence[str] = LIBRARIES, keep_sections: bool = False) -> None:
    """Print a result and write it to results/<name>.md, ending with :func:`machine`.

    :param keep_sections: keep the file's ``## `` sections that ``body`` does not have
        (see :func:`merge_sections`), for benchmarks whose parts can run alone.
    """
    RESULTS.mkdir(exist_ok=True)
    if keep_sections:
        body = merge_sections(RESULTS / f"{name}.md", body)
    text = f"# {title}\n\n{body.rstrip()}\n\n{machine(libraries)}\n"
    (RESULTS / f"{name}.md").write_text(text)
    print(text)


def merge_sections(path: Path, body: str) -> str:
    """The existing ``path``'s ``## `` sections in their order, those that ``body`` has replaced by
    ``body`` (where the first of them stood; first when none did), the others kept with their heading
    marked as from an earlier run on the machine named there: a run of some parts updates only what
    it measured, and a page's sections keep their order whichever part ran last."""
    if not path.exists():
        return body
    old = path.read_text().rstrip()
    last = old.rsplit("\n", 1)[-1]
    machine_line = last if last.startswith("Machine: ") else ""
    old = old[: len(old) - len(machine_line)].rstrip()
    mark = " (earlier run"
    parts: list[str] = []
    placed = False
    for section in old.split("\n## ")[1:]:
        heading, rest = (section.split("\n", 1) + [""])[:2]
        if f"## {heading.split(mark)[0]}\n" in body:
            if not placed:
                parts.append(body.strip("\n"))
                placed = True
            continue
        if mark not in heading:
            heading += f"{mark})"
            rest = f"\n{machine_line or 'Machine: not recorded.'} (The machine of that run.)\n{rest}"
        parts.append(f"## {heading}\n{rest.strip(chr(10))}")
    if not placed:
        parts.insert(0, body.strip("\n"))
    return "\n\n".join(parts) + "\n"
