"""Hostile and unlucky inputs: logs from strangers, tiny files that ask for gigabytes,
failures that used to look like successes, and the tracebacks users met.

Every crafted file is generated here. The bad-input cases run through the real CLI in
one subprocess under an address-space limit (:data:`MEMORY_LIMIT`: several of these
inputs used to take 4 to 24 GB), and each asserts its exit code, its one-line message
(no traceback) and that its input files are unchanged. Signals, a full disk and
campaigns get their own processes below; the seeded fuzz test is at the end.
"""

from __future__ import annotations

import collections
import contextlib
import hashlib
import io
import json
import os
import random
import signal
import struct
import subprocess
import sys
import textwrap
import time
import traceback
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import lz4.frame
import numpy as np
import pytest
import yaml
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Metadata
from mcap.records import Message as MessageRecord

from slamfront.campaign.store import CampaignStore
from slamfront.cli import main
from slamfront.mcaplog.reader import read_attachment, read_messages, summarize
from slamfront.mcaplog.scan import MAGIC, RecordScanner
from slamfront.mcaplog.writer import RunLogWriter
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.runtime import run_pipeline
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from tests import crafted_logs
from tests.helpers import rewrite_log

MEMORY_LIMIT = 3 << 30
"""Address space of the CLI process (bytes); peak resident memory must stay far below it."""
MAX_RSS = 3 << 29
"""1.5 GiB: one process runs every case, and the libraries its runs load (Open3D, GTSAM,
OpenCV, numba's LLVM) stay resident at about 1 GiB; the inputs' bombs took 4.3-24 GB."""
SINGLE_THREADED = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}

BASE_RECIPE: dict[str, Any] = {
    "name": "hostile",
    "source": {"plugin": "synthetic", "params": {
        "frames_per_traversal": 8, "route_length_m": 40, "image_width": 32, "image_height": 24,
    }},
    "descriptor": {"plugin": "downsampled", "params": {"width": 8, "height": 8}},
    "loop_detector": {"plugin": "nearest_neighbour", "params": {}},
    "log": {"chunk_size": 2048, "sync_seconds": None},
    "eval": {"plots": False, "retrieval_max_k": 0},
}

# -- running the CLI under a memory limit ---------------------------------------------------

_RUNNER = r"""
import contextlib, io, json, os, resource, signal, sys, traceback
limit, cases = int(sys.argv[1]), json.load(open(sys.argv[2]))
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from slamfront.cli import main

class Timeout(Exception):
    pass

def on_alarm(signum, frame):
    raise Timeout("the case took more than 120 s")

signal.signal(signal.SIGALRM, on_alarm)
home, results = os.getcwd(), {}
for name, case in cases.items():
    out, err = io.StringIO(), io.StringIO()
    saved = {k: os.environ.get(k) for k in case["env"]}
    os.environ.update(case["env"])
    os.chdir(case["cwd"] or home)
    signal.alarm(120)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(case["argv"])
    except BaseException:
        code = "traceback"
        err.write(traceback.format_exc())
    finally:
        signal.alarm(0)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    results[name] = {"code": code, "out": out.getvalue(), "err": err.getvalue()}
results["_max_rss_kib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
json.dump(results, open(sys.argv[3], "w"))
"""


@dataclass
class Case:
    """One CLI invocation with a crafted input, and what must come of it."""

    argv: list[Any]
    needles: tuple[str, ...] = ()
    """Substrings of the error line (exit 2) or of stdout (exit 0/1)."""
    code: int = 2
    inputs: tuple[Path, ...] = ()
    """Files that must be byte-identical afterwards."""
    absent: tuple[Path, ...] = ()
    """Paths that must not exist afterwards (what crafted code would have written)."""
    env: dict[str, str] = field(default_factory=dict)
    cwd: Path | None = None
    forbidden: tuple[str, ...] = ()
    """Substrings that must not appear in stdout."""


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run_cases(cases: dict[str, Case], folder: Path) -> tuple[dict[str, dict[str, Any]], int]:
    """Run every case in one CLI process under :data:`MEMORY_LIMIT`; returns the outcomes
    and the process's peak resident memory in KiB."""
    spec = {
        name: {"argv": [str(a) for a in case.argv], "env": case.env, "cwd": str(case.cwd) if case.cwd else None}
        for name, case in cases.items()
    }
    (folder / "cases.json").write_text(json.dumps(spec))
    env = {**os.environ, **SINGLE_THREADED}
    subprocess.run(
        [sys.executable, "-c", _RUNNER, str(MEMORY_LIMIT), str(folder / "cases.json"), str(folder / "results.json")],
        cwd=folder, env=env, check=True, timeout=1800,
    )
    results = json.loads((folder / "results.json").read_text())
    return results, results.pop("_max_rss_kib")


def assert_one_line_error(code: Any, err: str, *needles: str) -> None:
    assert code == 2, err
    assert err.startswith("slamfront: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, f"{needle!r} not in {err!r}"


# -- crafting inputs ----------------------------------------------------------------------


def with_recipe(log: Path, target: Path, change: Any) -> Path:
    """A copy of ``log`` whose embedded recipe is ``change(recipe dict)`` (or raw bytes)."""

    def attachment(name: str, data: bytes) -> bytes:
        if name != "recipe.yaml":
            return data
        changed = change(yaml.safe_load(data))
        return changed if isinstance(changed, bytes) else yaml.safe_dump(changed).encode()

    rewrite_log(log, target, attachment=attachment)
    return target


def with_message(log: Path, target: Path, prefix: str, change: Any) -> Path:
    """A copy of ``log`` whose first message on a topic starting with ``prefix`` is
    replaced by ``change(data)``."""
    done: list[bool] = []

    def message(topic: str, _index: int, data: bytes) -> bytes:
        if topic.startswith(prefix) and not done:
            done.append(True)
            return change(data)
        return data

    rewrite_log(log, target, message)
    return target


def record_offsets(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of every top-level record up to the footer."""
    found, position = [], len(MAGIC)
    while position + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, position)
        found.append((position, opcode, length))
        if opcode == 0x02:
            break
        position += 9 + length
    return found


def chunk_offsets(data: bytes) -> list[int]:
    return [offset for offset, opcode, _ in record_offsets(data) if opcode == 0x06]


def bomb_log(path: Path, declared: int, compression: str = "zstd") -> Path:
    """A small MCAP whose one chunk inflates to 4 GiB of zeros (zstd, 130 KB) or 128 MiB
    (lz4, which compresses less), declaring ``declared`` bytes of content: 32
    concatenated frames."""
    if compression == "zstd":
        frame = zstandard.compress(b"\0" * (128 << 20))
    else:
        frame = lz4.frame.compress(b"\0" * (4 << 20))
    builder = RecordBuilder()
    Header(profile="", library="crafted").write(builder)
    Chunk(compression=compression, data=frame * 32, message_start_time=0, message_end_time=0,
          uncompressed_crc=0, uncompressed_size=declared).write(builder)
    DataEnd(0).write(builder)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
    path.write_bytes(MAGIC + builder.end() + MAGIC)
    return path


def _with_image(data: bytes, encoded: bytes) -> bytes:
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    message = CompressedImage.FromString(data)
    message.data = encoded
    return message.SerializeToString()


def png_declaring(width: int, height: int) -> bytes:
    """A small PNG whose header declares ``width`` x ``height`` RGB pixels (its data holds a few rows)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return MAGIC_PNG + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(bytes(1 << 16))) + chunk(b"IEND", b"")


MAGIC_PNG = b"\x89PNG\r\n\x1a\n"


def write_module(folder: Path, name: str, source: str) -> Path:
    path = folder / f"{name}.py"
    path.write_text(textwrap.dedent(source))
    return path


MARKER_MODULE = """
    from pathlib import Path
    Path({marker!r}).write_text("code from a log ran")
"""


def evil_npy(path: Path, marker: Path) -> Path:
    class Evil:
        def __reduce__(self) -> tuple[Any, ...]:
            return (os.system, (f"touch {marker}",))

    table = np.empty((1, 2), dtype=object)
    table[0, 0], table[0, 1] = 0, Evil()
    np.save(path, table)  # an object array: np.save pickles it
    return path


# -- the base log -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def base_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("base") / "run"
    recipe = parse_recipe(BASE_RECIPE, "hostile.yaml")
    return run_pipeline(build_pipeline(recipe, "hostile.yaml"), "hostile.yaml", out, progress=False).log_path


# -- the bad-input cases, run in one process under a memory limit ----------------------------


def build_cases(tmp: Path, log: Path) -> dict[str, Case]:  # noqa: PLR0915 (one case after another)
    cases: dict[str, Case] = {}
    blocker = tmp / "a_file"
    blocker.write_text("not a folder")

    # 1. a log is data, never code
    marker = tmp / "evilmod_ran"
    write_module(tmp, "evilmod", MARKER_MODULE.format(marker=str(marker)))
    foreign = with_recipe(log, tmp / "foreign.mcap", lambda r: {**r, "plugin_modules": ["evilmod"]})
    cases["replay_refuses_plugin_modules"] = Case(
        ["replay", foreign, "-o", tmp / "r1", "-q"], ("plugin_modules", "--trust-log"),
        inputs=(foreign,), absent=(marker,), cwd=tmp)
    cases["replay_with_set_refuses_plugin_modules"] = Case(
        ["replay", foreign, "-o", tmp / "r2", "-q", "--set", "loop_detector.params.threshold=0.3"],
        ("plugin_modules",), inputs=(foreign,), absent=(marker,), cwd=tmp)
    cases["inspect_validate_notes_plugin_modules"] = Case(
        ["inspect", foreign, "--validate"], ("note:", "plugin_modules", "--trust-log"), code=0,
        inputs=(foreign,), absent=(marker,), cwd=tmp)
    path_field = with_recipe(log, tmp / "path_field.mcap", lambda r: {**r, "source": {
        "plugin": "rgbd_folder", "params": {"root": "rgbd/redwood_sample", "match_file": "../../../../etc/passwd"}}})
    cases["replay_refuses_paths_outside_the_data_root"] = Case(
        ["replay", path_field, "-o", tmp / "r3", "-q"], ("source.params.match_file", "outside the data root"),
        inputs=(path_field,))
    named = with_recipe(log, tmp / "named.mcap", lambda r: {**r, "name": "../../escaped"})
    work = tmp / "work" / "deeper"
    work.mkdir(parents=True)
    cases["replay_default_output_name_is_sanitised"] = Case(
        ["replay", named, "-q"], ("logs/escaped_replay/run.mcap",), code=0, inputs=(named,), cwd=work,
        absent=(tmp / "escaped_replay", tmp / "work" / "escaped_replay"))
    pickled = tmp / "vpr"
    for folder in ("ref", "query"):
        (pickled / folder).mkdir(parents=True)
        cv2.imwrite(str(pickled / folder / "0.png"), np.full((24, 32, 3), 128, np.uint8))
    pickle_marker = tmp / "pickle_ran"
    evil_npy(pickled / "ground_truth_new.npy", pickle_marker)
    vpr_recipe = tmp / "vpr.yaml"
    vpr_recipe.write_text(yaml.safe_dump({**BASE_RECIPE, "source": {"plugin": "vpr_bench", "params": {"root": str(pickled)}}}))
    cases["npy_ground_truth_is_never_unpickled_into_code"] = Case(
        ["run", vpr_recipe, "-o", tmp / "r4", "-q"], ("ground_truth_new.npy", "refused"),
        inputs=(pickled / "ground_truth_new.npy",), absent=(pickle_marker,))
    link = tmp / "hard_link.mcap"
    os.link(foreign, link)
    cases["recover_onto_a_hard_link_of_its_input"] = Case(
        ["recover", foreign, "-o", link], ("the same file on disk",), inputs=(foreign,))
    linked_out = tmp / "linked_out"
    linked_out.mkdir()
    os.link(log, linked_out / "run.mcap")
    cases["replay_onto_a_hard_link_of_its_input"] = Case(
        ["replay", log, "-o", linked_out, "-q"], ("cannot overwrite the log it reads",), inputs=(log,))
    symlinked_out = tmp / "symlinked_out"
    symlinked_out.mkdir()
    (symlinked_out / "run.mcap").symlink_to(log)
    cases["replay_onto_a_symbolic_link_to_its_input"] = Case(
        ["replay", log, "-o", symlinked_out, "-q"], ("cannot overwrite the log it reads",), inputs=(log,))
    escapes = with_recipe(  # raw bytes: a YAML writer would have escaped them
        log, tmp / "escapes.mcap", lambda r: b"# \x1b]0;owned\x07\x1b[2J\r\n" + yaml.safe_dump(r).encode())
    cases["inspect_recipe_neutralises_terminal_escapes"] = Case(
        ["inspect", escapes, "--recipe"], ("\\x1b]0;owned",), code=0, inputs=(escapes,), forbidden=("\x1b", "\x07"))
    strange = tmp / "strange.mcap"
    with RunLogWriter(strange) as writer:
        writer.write_raw("/evil\x1b[2J", "x", "", b"", "json", b"{}", 1)
        writer.add_metadata("meta\x1b]0;t\x07", {"key": "\x1b[31mred"})
    cases["inspect_summary_neutralises_terminal_escapes"] = Case(
        ["inspect", strange], ("/evil\\x1b[2J",), code=0, inputs=(strange,), forbidden=("\x1b", "\x07"))
    dataset = tmp / "rgbd"
    (dataset / "color").mkdir(parents=True)
    (dataset / "match.txt").write_text("../../../../etc/hostname ../../../../etc/hostname\n")
    rgbd_recipe = tmp / "rgbd.yaml"
    rgbd_recipe.write_text(yaml.safe_dump({
        "name": "rgbd", "source": {"plugin": "rgbd_folder", "params": {"root": str(dataset), "match_file": "match.txt"}},
        "descriptor": {"plugin": "downsampled"}, "loop_detector": {"plugin": "nearest_neighbour"},
    }))
    cases["match_file_entries_stay_in_the_dataset_folder"] = Case(
        ["run", rgbd_recipe, "-o", tmp / "r5", "-q"], ("match.txt:1", "leads outside the dataset folder"),
        inputs=(dataset / "match.txt",))

    # 2. tiny inputs cannot ask for huge memory
    laughs = ["a: &a [" + ", ".join(['"lol"'] * 9) + "]"]
    for name, previous in zip("bcdefghi", "abcdefgh"):
        laughs.append(f"{name}: &{name} [" + ", ".join([f"*{previous}"] * 9) + "]")
    bomb = tmp / "bomb.yaml"
    bomb.write_text("\n".join(laughs) + "\n")
    cases["yaml_alias_bomb"] = Case(["run", bomb, "-o", tmp / "r6"], ("bomb.yaml", "aliases expanded", "yaml_nodes"),
                                    inputs=(bomb,))
    recursive = tmp / "recursive.yaml"
    recursive.write_text("name: r\nsource: &s {plugin: synthetic, params: {x: *s}}\n")
    cases["yaml_recursive_alias"] = Case(["run", recursive], ("recursive.yaml", "contains it"), inputs=(recursive,))
    deep = tmp / "deep.yaml"
    deep.write_text("name: " + "[" * 20000 + "]" * 20000 + "\n")
    cases["yaml_deep_nesting"] = Case(["run", deep], ("deep.yaml", "nested too deeply"), inputs=(deep,))
    # libyaml's composer recurses once per level: 60,000 levels crashed the interpreter (exit 139,
    # no message) before the depth check; the parser's events are now checked first
    deeper = tmp / "deeper.yaml"
    deeper.write_text("name: " + "[" * 60000 + "]" * 60000 + "\n")
    cases["yaml_deeper_nesting"] = Case(["run", deeper], ("deeper.yaml", "nested too deeply"), inputs=(deeper,))
    deep_map = tmp / "deep_map.yaml"
    deep_map.write_text("name: " + "{a: " * 60000 + "1" + "}" * 60000 + "\n")
    cases["yaml_deep_mapping"] = Case(["run", deep_map], ("deep_map.yaml", "nested too deeply"), inputs=(deep_map,))
    cases["set_deep_nesting"] = Case(["run", "demo", "--set", "name=" + "[" * 60000 + "]" * 60000],
                                     ("--set", "nested too deeply"))
    deep_sweep = tmp / "deep_sweep.yaml"
    deep_sweep.write_text("name: s\nrecipe: demo\ngrid: " + "[" * 60000 + "]" * 60000 + "\n")
    cases["sweep_deep_nesting"] = Case(["sweep", deep_sweep, "--dry-run"], ("deep_sweep.yaml", "nested too deeply"),
                                       inputs=(deep_sweep,))
    sweep_bomb = tmp / "sweep_bomb.yaml"
    sweep_bomb.write_text("\n".join(laughs) + "\nname: s\nrecipe: demo\n")
    cases["sweep_alias_bomb"] = Case(["sweep", sweep_bomb, "--dry-run"], ("aliases expanded",), inputs=(sweep_bomb,))
    huge_grid = tmp / "huge_grid.yaml"
    huge_grid.write_text(yaml.safe_dump({"name": "huge", "recipe": "demo", "grid": {
        "loop_detector.params.threshold": [i / 1000 for i in range(1000)],
        "source.params.seed": list(range(1000)), "source.params.shuffle_seed": list(range(1000))}}))
    assert huge_grid.stat().st_size < 30_000
    cases["sweep_of_a_billion_runs"] = Case(
        ["sweep", huge_grid, "--dry-run"], ("huge_grid.yaml: grid:", "1,000,000,000", "sweep_runs"), inputs=(huge_grid,))
    cases["frames_per_traversal_1e13"] = Case(
        ["run", "demo", "-o", tmp / "r7", "--set", "source.params.frames_per_traversal=10000000000000"],
        ("source.params.frames_per_traversal", "over the limit", "SLAMFRONT_LIMITS=frames="))
    cases["route_length_1e11"] = Case(
        ["run", "demo", "-o", tmp / "r8", "--set", "source.params.route_length_m=100000000000.0"],
        ("source.params.route_length_m", "world_length_m"))
    cases["limits_are_overridable"] = Case(
        ["run", "demo", "-o", tmp / "r9"], ("frames_per_traversal", "over the limit of 100 "),
        env={"SLAMFRONT_LIMITS": "frames=100"})
    # image bombs: the declared size is read from the header and checked before decoding
    bombs = tmp / "bombs"
    bombs.mkdir()
    cv2.imwrite(str(bombs / "0.png"), np.full((24, 32, 3), 128, np.uint8))
    (bombs / "1.png").write_bytes(png_declaring(20000, 20000))
    folder_recipe = tmp / "bomb_folder.yaml"
    folder_recipe.write_text(yaml.safe_dump({**BASE_RECIPE, "source": {"plugin": "image_folder", "params": {
        "folder": str(bombs)}}}))
    cases["png_bomb_in_an_image_folder"] = Case(
        ["run", folder_recipe, "-o", tmp / "rib", "-q"], ("1.png", "20000x20000", "image_pixels"),
        inputs=(bombs / "1.png",))
    capped = tmp / "capped"
    capped.mkdir()
    (capped / "0.png").write_bytes(png_declaring(40000, 40000))  # beyond OpenCV's own cap of 2^30 pixels
    capped_recipe = tmp / "capped.yaml"
    capped_recipe.write_text(yaml.safe_dump({**BASE_RECIPE, "source": {"plugin": "image_folder", "params": {
        "folder": str(capped)}}}))
    cases["png_beyond_opencvs_pixel_cap"] = Case(["run", capped_recipe, "-o", tmp / "ric", "-q"],
                                                 ("0.png", "40000x40000", "over the limit"))
    cases["png_beyond_opencvs_pixel_cap_with_the_limit_raised"] = Case(
        ["run", capped_recipe, "-o", tmp / "ric2", "-q"], ("0.png", "OpenCV's cap"),
        env={"SLAMFRONT_LIMITS": "image_pixels=2e9"})
    sequence = tmp / "rgbd_bomb"
    for folder in ("color", "depth"):
        (sequence / folder).mkdir(parents=True)
    cv2.imwrite(str(sequence / "color" / "0.png"), np.full((24, 32, 3), 128, np.uint8))
    (sequence / "depth" / "0.png").write_bytes(png_declaring(30000, 30000))
    rgbd_bomb = tmp / "rgbd_bomb.yaml"
    rgbd_bomb.write_text(yaml.safe_dump({**BASE_RECIPE, "source": {"plugin": "rgbd_folder", "params": {
        "root": str(sequence)}}}))
    cases["png_bomb_as_a_datasets_depth_image"] = Case(
        ["run", rgbd_bomb, "-o", tmp / "rid", "-q"], ("depth/0.png", "30000x30000", "image_pixels"))
    exact = run_pipeline(build_pipeline(parse_recipe({**BASE_RECIPE, "log": {
        **BASE_RECIPE["log"], "image_format": "png", "depth": True, "depth_encoding": "32FC1"}}, "exact.yaml"),
        "exact.yaml"), "exact.yaml", tmp / "exact", progress=False).log_path
    logged_bomb = with_message(exact, tmp / "logged_bomb.mcap", "/camera/image",
                               lambda data: _with_image(data, png_declaring(20000, 20000)))
    cases["png_bomb_in_a_log_replay"] = Case(
        ["replay", logged_bomb, "-o", tmp / "rilb", "-q", "--from", "descriptor"],
        ("logged_bomb.mcap", "/camera/image", "20000x20000", "image_pixels"), inputs=(logged_bomb,))
    declared = bomb_log(tmp / "bomb_declared.mcap", declared=4 << 30)
    undeclared = bomb_log(tmp / "bomb_undeclared.mcap", declared=1024)
    lz4_bomb = bomb_log(tmp / "bomb_lz4.mcap", declared=1024, compression="lz4")
    for name, path, why in (("declared", declared, "over the limit"), ("undeclared", undeclared, "not the 1024 declared"),
                            ("lz4", lz4_bomb, "not the 1024 declared")):
        assert path.stat().st_size < 600_000
        cases[f"decompression_bomb_{name}_inspect"] = Case(["inspect", path], (why,), inputs=(path,))
        cases[f"decompression_bomb_{name}_recover"] = Case(
            ["recover", path, "-o", tmp / f"fixed_{name}.mcap"], ("lost:", why), code=0, inputs=(path,))
        cases[f"decompression_bomb_{name}_replay"] = Case(["replay", path, "-o", tmp / f"rb_{name}"], (why,),
                                                          inputs=(path,))

    # 3. failures that looked like successes
    data = bytearray(log.read_bytes())
    third = chunk_offsets(bytes(data))[2]
    data[third + 60] ^= 0x5A
    damaged = tmp / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    cases["inspect_exits_2_on_a_damaged_chunk"] = Case(["inspect", damaged], (f"chunk at byte {third}",), inputs=(damaged,))
    cases["replay_refuses_a_damaged_log"] = Case(
        ["replay", damaged, "-o", tmp / "r10", "-q"], ("damaged", "--salvage"), inputs=(damaged,))
    cases["replay_salvage_says_what_was_lost"] = Case(
        ["replay", damaged, "-o", tmp / "r11", "-q", "--salvage"], ("warning:", "lost:", f"chunk at byte {third}"),
        code=0, inputs=(damaged,))
    garbage = tmp / "garbage.mcap"
    garbage.write_bytes(log.read_bytes() + random.Random(4).randbytes(4096))
    cases["trailing_garbage_inspect"] = Case(["inspect", garbage], ("4096 bytes of unexpected data",), inputs=(garbage,))
    cases["trailing_garbage_validate"] = Case(["inspect", garbage, "--validate"], ("4096 bytes",), inputs=(garbage,))
    cases["trailing_garbage_recover"] = Case(
        ["recover", garbage, "-o", tmp / "fixed_garbage.mcap"], ("lost:", "4096 bytes of unexpected data"),
        code=0, inputs=(garbage,), forbidden=("complete and undamaged",))
    tolerances = tmp / "r12"
    cases["negative_tolerance_is_refused_before_the_run"] = Case(
        ["run", "demo", "-o", tolerances, "--set", "eval.tolerances=[-5]"], ("eval.tolerances.0",),
        absent=(tolerances / "run.mcap",))

    # 5. tracebacks users met
    for command in (["run", "demo"], ["replay", log], ["optimize", tmp / "graph.g2o"], ["sweep", "synthetic_nn"]):
        cases[f"uncreatable_output_folder_{command[0]}"] = Case(
            [*command, "-o", blocker / "out", "-q"] if command[0] != "optimize" else [*command, "-o", blocker / "out"],
            ("a_file/out", "cannot create"), inputs=(blocker,))
    (tmp / "graph.g2o").write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    binary = tmp / "binary.yaml"
    binary.write_bytes(bytes([0xB3, 0x00, 0xFF, 0x81]) * 64)
    cases["binary_recipe"] = Case(["run", binary], ("binary.yaml", "UTF-8"), inputs=(binary,))
    cases["binary_sweep"] = Case(["sweep", binary, "--dry-run"], ("binary.yaml", "UTF-8"), inputs=(binary,))
    huge_id = tmp / "huge_id.g2o"
    huge_id.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 100000000000000000000000 1 0 0\n"
                       "EDGE_SE2 0 100000000000000000000000 1 0 0 1 0 0 1 0 1\n")
    cases["g2o_vertex_id_1e23"] = Case(["optimize", huge_id, "-o", tmp / "r13"], ("huge_id.g2o:2", "64-bit"),
                                       inputs=(huge_id,))
    trajectory = tmp / "traj.txt"
    trajectory.write_text("".join(f"{t} {t} 0 0 0 0 0 1\n" for t in range(10)))
    cases["eval_traj_plot_into_a_missing_folder"] = Case(
        ["eval", "traj", trajectory, trajectory, "--plot", tmp / "missing" / "deeper" / "plot.png"], ("ate_rmse_m",),
        code=0, inputs=(trajectory,))

    # crafted logs: well-formed files whose messages were re-encoded, repeated, reordered or dropped
    for name, change, needles in (
        ("cbor_encoding", crafted_logs.with_encoding("/descriptor/", "cbor"), ("/descriptor/", "'cbor'")),
        ("frames_written_three_times", crafted_logs.repeated("/frames", 3), ("/frames", "frame 0 after frame 0")),
        ("frames_out_of_order", crafted_logs.swapped("/frames", 2), ("/frames", "frame 2 after frame 3")),
        ("a_frame_message_dropped", crafted_logs.dropped("/frames", 3), ("/frames", "1 message missing")),
        ("a_message_duplicated", crafted_logs.repeated("/frames", 2, renumber=False),
         ("/frames", "a duplicated or reordered message")),
        ("a_descriptor_relabelled", lambda m: [replace(e, schema_name="slamfront.FrameInfo")
                                               if e.topic.startswith("/descriptor/features") else e for e in m],
         ("/descriptor/features", "slamfront.FrameInfo")),
    ):
        crafted = crafted_logs.craft(log, tmp / f"crafted_{name}.mcap", change)
        cases[f"crafted_log_{name}_validate"] = Case(["inspect", crafted, "--validate"], needles, inputs=(crafted,))
        cases[f"crafted_log_{name}_replay"] = Case(["replay", crafted, "-o", tmp / f"rcl_{name}", "-q"], needles,
                                                   inputs=(crafted,), absent=(tmp / f"rcl_{name}",))
        cases[f"crafted_log_{name}_recover"] = Case(["recover", crafted, "-o", tmp / f"rcl_{name}.mcap"],
                                                    ("changed: ", needles[0]), code=0, inputs=(crafted,),
                                                    forbidden=("complete and undamaged",))
    unchanged = crafted_logs.craft(log, tmp / "crafted_unchanged.mcap", lambda messages: messages)
    cases["crafted_log_unchanged_validate"] = Case(["inspect", unchanged, "--validate"], ("valid:",), code=0)

    # eval traj: timestamps that repeat or go back; --max-frames; inspect on a FIFO
    twice = tmp / "twice.txt"  # an estimate written twice over: 0.0-2.4 s, then 0.0-2.4 s again
    twice.write_text("".join(f"{t / 10:.1f} {t + 50 * k} 0 0 0 0 0 1\n" for k in range(2) for t in range(25)))
    truth = tmp / "truth.txt"
    truth.write_text("".join(f"{t / 10:.1f} {t} 0 0 0 0 0 1\n" for t in range(25)))
    cases["eval_traj_repeated_timestamps"] = Case(
        ["eval", "traj", truth, twice], ("twice.txt", "25 of its 50 timestamps repeat", "1 go back", "--repeated"))
    cases["eval_traj_repeated_timestamps_keep_first"] = Case(
        ["eval", "traj", truth, twice, "--repeated", "first"], ("associated:   25 pose pairs",),
        code=0)
    backwards = tmp / "backwards.txt"
    backwards.write_text("".join(reversed(truth.read_text().splitlines(keepends=True))))
    cases["eval_traj_decreasing_timestamps"] = Case(["eval", "traj", truth, backwards],
                                                    ("backwards.txt", "0 of its 25", "24 go back"))
    cases["max_frames_minus_one"] = Case(["run", "demo", "-o", tmp / "rmf", "--max-frames", "-1"],
                                         ("--max-frames -1", "at least 1"), absent=(tmp / "rmf",))
    cases["max_frames_zero_in_a_sweep"] = Case(["sweep", "synthetic_nn", "--dry-run", "--max-frames", "0"],
                                               ("--max-frames 0", "at least 1"))
    fifo = tmp / "a_fifo.mcap"
    os.mkfifo(fifo)
    cases["inspect_a_fifo"] = Case(["inspect", fifo], ("a_fifo.mcap", "is a FIFO"))
    cases["replay_a_fifo"] = Case(["replay", fifo, "-o", tmp / "rff", "-q"], ("a_fifo.mcap", "is a FIFO"))

    def not_json(_data: bytes) -> bytes:
        return b"{this is not JSON"

    def object_dtype(data: bytes) -> bytes:
        message = json.loads(data)
        message["vector"]["dtype"] = "|O"
        return json.dumps(message).encode()

    def wrong_shape(data: bytes) -> bytes:
        message = json.loads(data)
        message["vector"]["shape"] = [3, 5]
        return json.dumps(message).encode()

    for name, change in (("not_json", not_json), ("object_dtype", object_dtype), ("wrong_shape", wrong_shape)):
        crafted = with_message(log, tmp / f"crafted_{name}.mcap", "/descriptor/", change)
        cases[f"crafted_message_{name}_replay"] = Case(
            ["replay", crafted, "-o", tmp / f"rc_{name}", "-q"], ("/descriptor/", "does not decode"), inputs=(crafted,))
        cases[f"crafted_message_{name}_diff"] = Case(["diff", log, crafted], ("/descriptor/",), code=1,
                                                      inputs=(crafted, log))
    deep_json = with_message(log, tmp / "deep_json.mcap", "/descriptor/", lambda _d: b"[" * 100_000 + b"]" * 100_000)
    cases["deeply_nested_json_validate"] = Case(["inspect", deep_json, "--validate"], ("problem(s) found by --validate",),
                                                inputs=(deep_json,))
    binary_recipe = with_recipe(log, tmp / "binary_recipe.mcap", lambda _r: bytes(range(128, 256)))
    cases["binary_recipe_attachment"] = Case(["inspect", binary_recipe, "--recipe"], ("recipe.yaml", "not UTF-8"),
                                             inputs=(binary_recipe,))
    return cases


CASE_NAMES = [
    "replay_refuses_plugin_modules", "replay_with_set_refuses_plugin_modules", "inspect_validate_notes_plugin_modules",
    "replay_refuses_paths_outside_the_data_root", "replay_default_output_name_is_sanitised",
    "npy_ground_truth_is_never_unpickled_into_code", "recover_onto_a_hard_link_of_its_input",
    "replay_onto_a_hard_link_of_its_input", "replay_onto_a_symbolic_link_to_its_input",
    "inspect_recipe_neutralises_terminal_escapes", "inspect_summary_neutralises_terminal_escapes",
    "match_file_entries_stay_in_the_dataset_folder",
    "yaml_alias_bomb", "yaml_recursive_alias", "yaml_deep_nesting", "yaml_deeper_nesting", "yaml_deep_mapping",
    "set_deep_nesting", "sweep_deep_nesting", "sweep_alias_bomb", "sweep_of_a_billion_runs",
    "frames_per_traversal_1e13", "route_length_1e11", "limits_are_overridable",
    "png_bomb_in_an_image_folder", "png_beyond_opencvs_pixel_cap", "png_beyond_opencvs_pixel_cap_with_the_limit_raised",
    "png_bomb_as_a_datasets_depth_image", "png_bomb_in_a_log_replay",
    *(f"decompression_bomb_{kind}_{command}" for kind in ("declared", "undeclared", "lz4")
      for command in ("inspect", "recover", "replay")),
    "inspect_exits_2_on_a_damaged_chunk", "replay_refuses_a_damaged_log", "replay_salvage_says_what_was_lost",
    "trailing_garbage_inspect", "trailing_garbage_validate", "trailing_garbage_recover",
    "negative_tolerance_is_refused_before_the_run",
    *(f"uncreatable_output_folder_{command}" for command in ("run", "replay", "optimize", "sweep")),
    "binary_recipe", "binary_sweep", "g2o_vertex_id_1e23", "eval_traj_plot_into_a_missing_folder",
    *(f"crafted_message_{name}_{command}" for name in ("not_json", "object_dtype", "wrong_shape")
      for command in ("replay", "diff")),
    "deeply_nested_json_validate", "binary_recipe_attachment",
    *(f"crafted_log_{name}_{command}" for name in (
        "cbor_encoding", "frames_written_three_times", "frames_out_of_order", "a_frame_message_dropped",
        "a_message_duplicated", "a_descriptor_relabelled") for command in ("validate", "replay", "recover")),
    "crafted_log_unchanged_validate", "eval_traj_repeated_timestamps", "eval_traj_repeated_timestamps_keep_first",
    "eval_traj_decreasing_timestamps", "max_frames_minus_one", "max_frames_zero_in_a_sweep", "inspect_a_fifo",
    "replay_a_fifo",
]


@dataclass
class Ran:
    cases: dict[str, Case]
    outcomes: dict[str, dict[str, Any]]
    before: dict[Path, str]
    after: dict[Path, str]
    max_rss_kib: int


@pytest.fixture(scope="module")
def ran(tmp_path_factory: pytest.TempPathFactory, base_log: Path) -> Ran:
    tmp = tmp_path_factory.mktemp("hostile")
    cases = build_cases(tmp, base_log)
    inputs = {path for case in cases.values() for path in case.inputs}
    before = {path: _digest(path) for path in inputs}
    outcomes, max_rss = run_cases(cases, tmp)
    return Ran(cases, outcomes, before, {path: _digest(path) for path in inputs}, max_rss)


def test_every_case_is_listed(ran: Ran) -> None:
    assert sorted(ran.cases) == sorted(CASE_NAMES)


@pytest.mark.parametrize("name", CASE_NAMES)
def test_hostile_input(ran: Ran, name: str) -> None:
    case, outcome = ran.cases[name], ran.outcomes[name]
    code, out, err = outcome["code"], outcome["out"], outcome["err"]
    assert "Traceback" not in err and "Traceback" not in out, err
    if case.code == 2:
        assert_one_line_error(code, err, *case.needles)
    else:
        assert code == case.code, err
        for needle in case.needles:
            assert needle in out, f"{needle!r} not in {out!r}"
    for text in case.forbidden:
        assert text not in out
    for path in case.inputs:
        assert ran.after[path] == ran.before[path], f"{path} was changed"
    for path in case.absent:
        assert not path.exists(), f"{path} exists"


def test_every_hostile_input_ran_in_bounded_memory(ran: Ran) -> None:
    # the alias bomb took 8.4 GB, the sweep 24 GB, the frame count 19 GB, the chunk bomb 4.3 GB
    assert ran.max_rss_kib * 1024 < MAX_RSS


def test_a_yaml_bomb_gets_a_short_message(ran: Ran) -> None:
    assert len(ran.outcomes["yaml_alias_bomb"]["err"]) < 400  # it used to print ~2 GiB


def test_salvaged_replay_logs_what_was_lost(ran: Ran) -> None:
    log = ran.cases["replay_salvage_says_what_was_lost"].argv[3] / "run.mcap"
    last = [m.decoded.message for m in read_messages(log, ["/log"])][-1]
    assert last.startswith("run completed") and "the log is damaged" in last and "lost: damaged chunk at byte" in last


# -- resynchronising on the chunk after a damaged length field ------------------------------


def test_recover_reads_on_after_a_damaged_chunk_length(base_log: Path, tmp_path: Path, cli) -> None:
    data = base_log.read_bytes()
    original = [(m.topic, m.log_time_ns, m.data) for m in read_messages(base_log)]
    offset = chunk_offsets(data)[1]
    (length,) = struct.unpack_from("<Q", data, offset + 1)
    no_summary = next(o for o, opcode, _ in record_offsets(data) if opcode == 0x0F)
    for new_length, cut in ((length + 5000, len(data)), (1 << 50, len(data)), (17, len(data)), (1 << 50, no_summary)):
        broken = bytearray(data[:cut])
        struct.pack_into("<Q", broken, offset + 1, new_length)
        path = tmp_path / "broken.mcap"
        path.write_bytes(bytes(broken))
        code, _, err = cli("inspect", path)
        assert_one_line_error(code, err, "damaged length field")
        code, out, _ = cli("recover", path, "-o", tmp_path / "fixed.mcap")
        kept = [(m.topic, m.log_time_ns, m.data) for m in read_messages(tmp_path / "fixed.mcap") if m.topic != "/log"]
        assert code == 0 and "lost:" in out and "was kept" in out
        assert kept == [m for m in original if m[0] != "/log"]  # nothing lost: the content said where it ends

    # garbage where a chunk starts, without a summary to say where the next one is: found by its shape
    broken = bytearray(data[:no_summary])
    broken[offset : offset + 9] = b"\xee" * 9
    path = tmp_path / "garbage_head.mcap"
    path.write_bytes(bytes(broken))
    code, out, _ = cli("recover", path, "-o", tmp_path / "fixed2.mcap")
    assert code == 0 and "reading goes on at byte" in out
    kept = [m.data for m in read_messages(tmp_path / "fixed2.mcap") if m.topic != "/log"]
    assert len(kept) > len(original) // 2  # every chunk after the damaged one is read


# -- honest outcomes: the last /log line, the exit code and the output folder ----------------


def _last_log_line(path: Path) -> str:
    return [m.decoded.message for m in read_messages(path, ["/log"])][-1]


def _subprocess_cli(args: list[Any], cwd: Path, **kwargs: Any) -> subprocess.Popen[bytes]:
    env = {**os.environ, **SINGLE_THREADED}
    setup = kwargs.pop("preexec_fn", None)

    def child_setup() -> None:
        # Ctrl-C as at a terminal: a suite started in the background (``make test &``) runs with
        # SIGINT ignored, which the child would inherit, and Python then never raises KeyboardInterrupt
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        if setup is not None:
            setup()

    return subprocess.Popen([sys.executable, "-m", "slamfront", *map(str, args)], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=child_setup, **kwargs)


def test_sigterm_while_plots_are_drawn(tmp_path: Path) -> None:
    write_module(tmp_path, "term_in_plots", """
        import os, signal
        import slamfront.report.plots as plots
        _draw = plots._finish
        def _finish(*args, **kwargs):
            os.kill(os.getpid(), signal.SIGTERM)
            return _draw(*args, **kwargs)
        plots._finish = _finish
    """)
    recipe = tmp_path / "plots.yaml"
    recipe.write_text(yaml.safe_dump({**BASE_RECIPE, "eval": {"plots": True}}))
    process = _subprocess_cli(["run", recipe, "-o", tmp_path / "out", "-q", "-p", "term_in_plots"], tmp_path)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr.decode()
    assert stderr.decode().count("\n") == 1 and "Traceback" not in stderr.decode()
    last = _last_log_line(tmp_path / "out" / "run.mcap")
    assert "interrupted (signal SIGTERM)" in last and "in evaluation" in last and "completed" not in last
    assert not (tmp_path / "out" / "metrics.json").exists()


def test_a_sigkill_in_the_first_second_keeps_the_recipe(tmp_path: Path, cli) -> None:
    out = tmp_path / "out"
    process = _subprocess_cli(["run", "demo", "-o", out, "-q"], tmp_path)
    log = out / "run.mcap"
    try:
        deadline = time.monotonic() + 300
        while not log.exists():
            assert process.poll() is None and time.monotonic() < deadline, process.stderr.read().decode()  # type: ignore[union-attr]
            time.sleep(0.01)
        created = time.monotonic()
        while True:
            with contextlib.suppress(Exception):
                recipe = read_attachment(log, "recipe.yaml")
                break
            assert time.monotonic() - created < 1.0, "the recipe is not on disk a second after the log was created"
            time.sleep(0.01)
    finally:
        process.kill()
        process.communicate()
    assert b"synthetic" in recipe
    code, out_text, _ = cli("recover", log, "-o", tmp_path / "fixed.mcap")
    assert code == 0 and "lost:" in out_text
    assert read_attachment(tmp_path / "fixed.mcap", "recipe.yaml") == recipe


def test_a_full_disk_is_one_line_and_what_was_written_is_recoverable(tmp_path: Path, cli) -> None:
    def small_files() -> None:
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit then fail with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, 150_000))

    process = _subprocess_cli(["run", "demo", "-o", tmp_path / "out", "-q"], tmp_path, preexec_fn=small_files)
    _, stderr = process.communicate(timeout=600)
    assert_one_line_error(process.returncode, stderr.decode(), "run.mcap", "cannot write the log", "slamfront recover")
    code, out, _ = cli("recover", tmp_path / "out" / "run.mcap", "-o", tmp_path / "fixed.mcap")
    assert code == 0 and "lost:" in out
    assert b"synthetic" in read_attachment(tmp_path / "fixed.mcap", "recipe.yaml")


def test_ctrl_c_during_start_up(tmp_path: Path) -> None:
    write_module(tmp_path, "interrupt_on_import", """
        import os, signal
        os.kill(os.getpid(), signal.SIGINT)
    """)
    process = _subprocess_cli(["run", "demo", "-o", tmp_path / "out", "-p", "interrupt_on_import"], tmp_path)
    _, stderr = process.communicate(timeout=300)
    text = stderr.decode()
    assert process.returncode == 130 and text.count("\n") == 1 and "Traceback" not in text, text
    assert text.startswith("slamfront: interrupted") and "finalised" not in text  # no log was open yet


def _recipe(**changes: Any) -> Any:
    raw = json.loads(json.dumps(BASE_RECIPE))
    for key, value in changes.items():
        raw[key] = {**raw.get(key, {}), **value}
    return parse_recipe(raw, "hostile.yaml")


def _run(out: Path, **changes: Any) -> Any:
    recipe = _recipe(**changes)
    return run_pipeline(build_pipeline(recipe, "hostile.yaml"), "hostile.yaml", out, progress=False)


def test_a_rerun_replaces_the_previous_runs_files_and_keeps_the_users(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    _run(out, eval={"plots": True})
    assert (out / "pr.png").exists()
    (out / "notes.txt").write_text("mine")
    _run(out)  # plots off: a pr.png left behind would describe the other run
    assert "held a previous run" in capsys.readouterr().err
    assert not (out / "pr.png").exists() and (out / "notes.txt").read_text() == "mine"


def test_an_interrupted_run_leaves_no_metrics_of_the_previous_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    _run(out)
    process = NearestNeighbour.process

    def interrupted(self: NearestNeighbour, inputs: Any) -> Any:
        if inputs.frame.index == 3:
            raise KeyboardInterrupt
        return process(self, inputs)

    monkeypatch.setattr(NearestNeighbour, "process", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _run(out)
    assert not (out / "metrics.json").exists() and not (out / "report.md").exists()
    assert summarize(out / "run.mcap").topic("/frames").count == 4
    assert "interrupted" in _last_log_line(out / "run.mcap")


# -- campaigns: one run's exit is that run's failure; one campaign per folder ---------------

EXITER = """
    import sys
    from pydantic import Field
    import slamfront
    from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour

    class Exiter(NearestNeighbour):
        \"\"\"Nearest neighbour that ends the process at the third frame (campaign isolation tests).\"\"\"

        name = "exiter"

        class Config(NearestNeighbour.Config):
            how: str = Field("exit", description="exit: sys.exit(7); interrupt: KeyboardInterrupt")

        def process(self, inputs):
            if inputs.frame.index == 2:
                if self.config.how == "exit":
                    sys.exit(7)
                raise KeyboardInterrupt
            return super().process(inputs)

    @slamfront.hookimpl
    def slamfront_loop_detectors():
        return [Exiter]
"""


def test_a_run_that_exits_fails_alone_and_campaigns_do_not_share_a_folder(
    tmp_path: Path, cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    write_module(tmp_path, "exiter", EXITER)
    (tmp_path / "exits.yaml").write_text(yaml.safe_dump({
        **BASE_RECIPE, "plugin_modules": ["exiter"], "loop_detector": {"plugin": "exiter", "params": {}}}))
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(yaml.safe_dump({"name": "exits", "recipe": "exits.yaml",
                                     "grid": {"loop_detector.params.how": ["exit", "interrupt"]}}))
    code, out, err = cli("sweep", sweep, "-o", tmp_path / "camp", "--workers", "1", "-q")
    assert code == 1 and "0 ok, 2 failed" in out, err
    rows = (tmp_path / "camp" / "results.csv").read_text()
    assert "SystemExit: 7" in rows and "KeyboardInterrupt" in rows

    with CampaignStore(tmp_path / "camp").locked():
        code, _, err = cli("sweep", sweep, "-o", tmp_path / "camp", "--workers", "1", "-q")
    assert_one_line_error(code, err, "another campaign", "camp")


# -- fuzz: seeded byte-level mutations of a small log ----------------------------------------

FUZZ_CASES = 240
SALVAGE_EVERY = 12
CASE_TIMEOUT_S = 30


def _content(path: Path) -> tuple[list[Any], list[Any], list[Any]]:
    """Messages (topic, time, bytes), metadata and attachments a scan reads."""
    messages, metadata, attachments, channels = [], [], [], {}
    with open(path, "rb") as stream:
        for record in RecordScanner(stream, path.stat().st_size).records():
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, MessageRecord) and record.channel_id in channels:
                messages.append((channels[record.channel_id], record.log_time, bytes(record.data)))
            elif isinstance(record, Metadata):
                metadata.append((record.name, sorted(record.metadata.items())))
            elif isinstance(record, Attachment):
                attachments.append((record.name, bytes(record.data)))
    return messages, metadata, attachments


def _mutate(data: bytes, rng: random.Random, records: list[tuple[int, int, int]]) -> tuple[str, bytes]:
    mutated, kind = bytearray(data), rng.choice(("flip", "truncate", "length", "append", "zero"))
    if kind == "flip":
        for _ in range(rng.randint(1, 3)):
            mutated[rng.randrange(len(mutated))] ^= rng.randint(1, 255)
    elif kind == "truncate":
        mutated = mutated[: rng.randrange(len(mutated))]
    elif kind == "length":
        offset, _, length = rng.choice(records)
        new = rng.choice((0, length + rng.randint(1, 64), max(0, length - rng.randint(1, 64)),
                          rng.getrandbits(63), length ^ (1 << rng.randrange(40))))
        struct.pack_into("<Q", mutated, offset + 1, new)
    elif kind == "append":
        mutated += rng.randbytes(rng.randint(1, 4096)) if rng.random() < 0.5 else data[rng.randrange(len(data)):]
    else:
        start = rng.randrange(len(mutated))
        mutated[start : start + rng.randint(1, 512)] = bytes(min(512, len(mutated) - start))
    return kind, bytes(mutated)


class _CaseTimeout(Exception):
    pass


@contextlib.contextmanager
def _time_limit(seconds: int) -> Iterator[None]:
    def expire(_signum: int, _frame: Any) -> None:
        raise _CaseTimeout

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _call(argv: list[Any]) -> tuple[Any, str, str]:
    out, err = io.StringIO(), io.StringIO()
    try:
        with _time_limit(CASE_TIMEOUT_S), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code: Any = main([str(a) for a in argv])
    except _CaseTimeout:
        code = "hang"
    except BaseException:  # noqa: BLE001 (a traceback is what the test looks for)
        code = "traceback"
        err.write(traceback.format_exc())
    return code, out.getvalue(), err.getvalue()


def test_fuzzed_logs_are_read_honestly(base_log: Path, tmp_path: Path) -> None:
    data = base_log.read_bytes()
    records = record_offsets(data)
    messages, metadata, attachments = _content(base_log)
    original = collections.Counter(messages)
    failures: list[str] = []
    seen: collections.Counter[tuple[str, Any]] = collections.Counter()
    started = time.monotonic()
    for seed in range(FUZZ_CASES):
        kind, mutated = _mutate(data, random.Random(seed), records)
        path = tmp_path / f"m{seed}.mcap"
        path.write_bytes(mutated)
        commands = [["inspect", path], ["inspect", path, "--validate"], ["recover", path, "-o", tmp_path / "fixed.mcap"],
                    ["replay", path, "-o", tmp_path / "replayed", "-q"]]
        if seed % SALVAGE_EVERY == 0:
            commands.append(["replay", path, "-o", tmp_path / "salvaged", "-q", "--salvage"])
        for argv in commands:
            code, out, err = _call(argv)
            label = " ".join(str(a) for a in argv if not str(a).startswith(str(tmp_path)))
            seen[(label, code)] += 1
            problem = None
            if code not in (0, 2):
                problem = f"exit {code}"
            elif code == 2 and not (err.startswith("slamfront: error: ") and err.count("\n") == 1):
                problem = "not a one-line error"
            elif code == 0 and mutated != data:
                if argv[0] == "inspect" or (argv[0] == "replay" and "--salvage" not in argv):
                    problem = "exit 0 although the file changed"
                elif argv[0] == "recover":
                    kept, kept_metadata, kept_attachments = _content(tmp_path / "fixed.mcap")
                    without_note = collections.Counter(m for m in kept if m[0] != "/log")
                    if without_note - original:
                        problem = "recover invented messages"
                    elif "complete and undamaged" in out:
                        if (kept, kept_metadata, kept_attachments) != (messages, metadata, attachments):
                            problem = "'undamaged' but the content differs"
                    elif "lost:" not in out:
                        problem = "no statement of what was lost"
                elif "warning:" not in out or "lost:" not in out:
                    problem = "a salvaged replay that does not say what was lost"
            if problem:
                failures.append(f"seed {seed} ({kind}), {label}: {problem}\n{(err or out)[-800:]}")
    elapsed = time.monotonic() - started
    assert not failures, f"{len(failures)} failures:\n" + "\n".join(failures[:5])
    assert sum(n for (label, _), n in seen.items() if label.startswith("inspect")) == 2 * FUZZ_CASES
    assert elapsed < 120 * max(1.0, os.getloadavg()[0] / (os.cpu_count() or 1)), f"{elapsed:.0f} s"


def test_the_crc_that_guards_every_byte_is_the_one_mcap_defines(base_log: Path) -> None:
    data = base_log.read_bytes()
    data_end = next(o for o, opcode, _ in record_offsets(data) if opcode == 0x0F)
    (crc,) = struct.unpack_from("<I", data, data_end + 9)
    assert crc != 0 and crc == zlib.crc32(data[:data_end])  # written with data CRCs on


def test_run_help_says_what_a_sigkill_can_lose(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "SIGKILL" in text and "log.sync_seconds" in text and "slamfront recover" in text


def test_decode_image_reads_the_declared_size_before_decoding(monkeypatch: pytest.MonkeyPatch) -> None:
    from slamfront.errors import DataError
    from slamfront.imageio import declared_size, decode_image

    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[..., 0] = 200  # red
    data = cv2.imencode(".png", rgb[..., ::-1])[1].tobytes()
    assert declared_size(data, "x") == (8, 6)
    assert decode_image(data, "x")[0, 0].tolist() == [200, 0, 0]
    assert decode_image(data, "x", "gray").shape == (6, 8)
    deep = cv2.imencode(".png", np.full((6, 8), 4000, np.uint16))[1].tobytes()
    assert decode_image(deep, "d", "unchanged").dtype == np.uint16 and decode_image(deep, "d")[0, 0, 0] == 4000 >> 8
    monkeypatch.setattr(cv2, "imdecode", lambda *_a: pytest.fail("decoded before the size was checked"))
    with pytest.raises(DataError, match=r"frame 3: .*20000x20000.*image_pixels"):
        decode_image(png_declaring(20000, 20000), "frame 3")
    monkeypatch.setenv("SLAMFRONT_LIMITS", "image_pixels=40")
    with pytest.raises(DataError, match="8x6"):
        decode_image(data, "x")
    with pytest.raises(DataError, match="no image format recognises its header"):
        decode_image(b"not an image at all", "x")
