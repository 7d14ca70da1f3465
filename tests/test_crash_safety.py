"""Logs survive how runs end: signals, exceptions in plugins, files cut short."""

from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader, breakup_chunk

from slamfront.interrupts import Interrupts, RunInterrupted
from slamfront.mcaplog.reader import read_messages, summarize
from slamfront.mcaplog.recover import recover_log
from slamfront.mcaplog.validate import validate_log
from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.runtime import run_pipeline
from slamfront_plugins.loop_detectors.nearest_neighbour import NearestNeighbour
from tests.helpers import small_synthetic_recipe


def _open_with_mcap_readers(path: Path) -> int:
    """Read the file as other MCAP tools do: indexed (summary) and streaming, CRCs checked."""
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        indexed = sum(1 for _ in reader.iter_messages())
        assert summary is not None and summary.statistics.message_count == indexed
    with open(path, "rb") as stream:
        streamed = sum(1 for r in StreamReader(stream, validate_crcs=True).records if type(r).__name__ == "Message")
    assert streamed == indexed
    return indexed


def _last_log_line(path: Path) -> str:
    return [m.decoded.message for m in read_messages(path, ["/log"])][-1]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_mid_run_leaves_a_finalised_log(signum: int, tmp_path: Path) -> None:
    out = tmp_path / "out"
    # sync often so the log visibly grows, which tells us frames are being processed
    command = [sys.executable, "-m", "slamfront", "run", "demo", "-o", str(out), "-q", "--set", "log.sync_seconds=0.05"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    log = out / "run.mcap"
    deadline = time.monotonic() + 120
    while not (log.exists() and log.stat().st_size > 60_000):
        assert process.poll() is None and time.monotonic() < deadline, process.stderr.read().decode()  # type: ignore[union-attr]
        time.sleep(0.05)
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr.decode()
    assert "interrupted" in stderr.decode() and "Traceback" not in stderr.decode()
    summary = summarize(log)
    assert summary.complete
    assert 0 < summary.topic("/frames").count < 800
    assert _open_with_mcap_readers(log) == summary.n_messages
    assert f"run interrupted (signal {signal.Signals(signum).name})" in _last_log_line(log)
    assert validate_log(log).valid


def test_a_plugin_that_raises_leaves_a_finalised_log(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    process = NearestNeighbour.process

    def failing(self: NearestNeighbour, inputs: Any) -> Any:
        if inputs.frame.index == 45:
            raise RuntimeError("boom")
        return process(self, inputs)

    monkeypatch.setattr(NearestNeighbour, "process", failing)
    recipe = parse_recipe(small_synthetic_recipe(), "r.yaml")
    with pytest.raises(RuntimeError, match="boom"):
        run_pipeline(build_pipeline(recipe, "r.yaml"), "r.yaml", tmp_path, progress=False)
    log = tmp_path / "run.mcap"
    summary = summarize(log)
    assert summary.complete and summary.topic("/frames").count == 46
    assert _open_with_mcap_readers(log) == summary.n_messages
    assert _last_log_line(log) == (
        "run failed after 45 frames in the loop_detector plugin 'nearest_neighbour' at frame 45: RuntimeError: boom"
    )
    assert "/ground_truth/loops" in {t.topic for t in summary.topics}
    assert validate_log(log).valid


def test_signals_wait_for_the_end_of_a_critical_section() -> None:
    previous = signal.getsignal(signal.SIGINT)
    with Interrupts() as interrupts:
        with pytest.raises(RunInterrupted, match="SIGINT"):
            with interrupts.critical():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.01)  # the handler has run by now, and held the interrupt back
                reached_the_end = True
        assert reached_the_end
        with pytest.raises(RunInterrupted, match="SIGTERM"):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)
    assert signal.getsignal(signal.SIGINT) is previous


def test_a_signal_while_the_log_is_being_created_leaves_a_finalised_log(tmp_path: Path) -> None:
    """The signal that lands between creating the file and writing its header (a sweep
    stopped just as a run starts) is raised once the header is written, after the log is
    finalised: never a zero-byte ``run.mcap`` in a folder the next run reads."""
    from slamfront.mcaplog.writer import RunLogWriter

    path = tmp_path / "run.mcap"
    with Interrupts() as interrupts:
        signalled = False

        @contextlib.contextmanager
        def critical() -> Iterator[None]:
            nonlocal signalled
            with interrupts.critical():
                if not signalled:
                    signalled = True
                    os.kill(os.getpid(), signal.SIGINT)  # held back until the section ends
                    time.sleep(0.01)
                yield

        with pytest.raises(RunInterrupted):
            RunLogWriter(path, critical=critical)
    assert summarize(path).complete and validate_log(path).valid


@pytest.fixture(scope="module")
def small_chunked_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("chunked")
    raw = small_synthetic_recipe()
    raw["log"] = {"chunk_size": 8192, "sync_seconds": None}
    recipe = parse_recipe(raw, "r.yaml")
    return run_pipeline(build_pipeline(recipe, "r.yaml"), "r.yaml", out, progress=False).log_path


def _messages_in_complete_chunks(path: Path) -> list[tuple[int, int]]:
    """(end offset of each chunk, messages in it), in file order."""
    chunks = []
    with open(path, "rb") as stream:
        for record in StreamReader(stream, emit_chunks=True).records:
            if isinstance(record, Chunk):
                count = sum(1 for r in breakup_chunk(record) if type(r).__name__ == "Message")
                chunks.append((stream.tell(), count))
    return chunks


def test_truncated_logs_are_inspected_and_recovered(small_chunked_log: Path, tmp_path: Path, cli) -> None:
    data = small_chunked_log.read_bytes()
    original = [(m.topic, m.log_time_ns, m.data) for m in read_messages(small_chunked_log)]
    chunks = _messages_in_complete_chunks(small_chunked_log)
    offsets = sorted(random.Random(9).sample(range(9, len(data)), 20))
    for offset in offsets:
        cut = tmp_path / f"cut{offset}.mcap"
        cut.write_bytes(data[:offset])
        code, stdout, err = cli("inspect", cut)
        assert code == 2 and "Traceback" not in err and err.count("\n") == 1, err
        assert "INCOMPLETE" in stdout
        summary = summarize(cut)
        assert not summary.complete and summary.problem

        fixed = tmp_path / f"fixed{offset}.mcap"
        code, stdout, _ = cli("recover", cut, "-o", fixed)
        assert code == 0 and "lost:" in stdout
        assert validate_log(fixed).valid
        *recovered, note = [(m.topic, m.log_time_ns, m.data) for m in read_messages(fixed)]
        assert note[0] == "/log"  # recover's own last line, after everything it kept
        # every message of every chunk that ends before the cut is kept, in order, unchanged
        complete = sum(count for end, count in chunks if end <= offset)
        assert len(recovered) >= complete
        assert recovered == original[: len(recovered)]
        assert "recovered by slamfront recover" in _last_log_line(fixed)
        assert summarize(fixed).metadata["recovery"]["source"] == str(cut)


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_recover_keeps_the_complete_messages_of_a_chunk_cut_in_two(compression: str, tmp_path: Path) -> None:
    raw = small_synthetic_recipe(image_width=160, image_height=120)
    raw["log"] = {"chunk_size": 1 << 26, "sync_seconds": None, "compression": compression, "image_format": "png"}
    recipe = parse_recipe(raw, "r.yaml")
    log = run_pipeline(build_pipeline(recipe, "r.yaml"), "r.yaml", tmp_path / "run", progress=False).log_path
    assert len(_messages_in_complete_chunks(log)) == 1  # everything in one chunk
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(log.read_bytes()[: log.stat().st_size * 6 // 10])
    summary = summarize(cut)
    assert summary.salvaged_messages > 0 and "recovered from the incomplete chunk" in summary.problem
    recovery = recover_log(cut, tmp_path / "fixed.mcap")
    assert recovery.salvaged_messages == summary.salvaged_messages == recovery.messages
    original = [m.data for m in read_messages(log)]
    *recovered, _note = [m.data for m in read_messages(tmp_path / "fixed.mcap")]
    assert recovered == original[: recovery.messages]


def test_a_complete_log_recovers_to_a_copy(small_chunked_log: Path, tmp_path: Path, cli) -> None:
    code, stdout, _ = cli("recover", small_chunked_log, "-o", tmp_path / "copy.mcap")
    assert code == 0 and "was complete and undamaged" in stdout
    assert [m.data for m in read_messages(tmp_path / "copy.mcap")] == [m.data for m in read_messages(small_chunked_log)]
    code, _, err = cli("recover", small_chunked_log, "-o", small_chunked_log)
    assert code == 2 and "choose another -o path" in err


def test_periodic_sync_closes_chunks(tmp_path: Path) -> None:
    raw = small_synthetic_recipe()
    raw["log"] = {"sync_seconds": 0.001}
    recipe = parse_recipe(raw, "r.yaml")
    result = run_pipeline(build_pipeline(recipe, "r.yaml"), "r.yaml", tmp_path, progress=False)
    assert result.metrics["log_syncs"] > 10
    assert len(_messages_in_complete_chunks(result.log_path)) > 10
    assert validate_log(result.log_path).valid


def test_a_damaged_chunk_is_skipped_and_reading_goes_on(small_chunked_log: Path, tmp_path: Path, cli) -> None:
    chunks = _messages_in_complete_chunks(small_chunked_log)
    data = bytearray(small_chunked_log.read_bytes())
    (second_end, second_count), (third_end, _) = chunks[1], chunks[2]
    data[second_end - 100] ^= 0xFF  # a flipped bit inside the second chunk's data
    cut = tmp_path / "damaged.mcap"
    cut.write_bytes(bytes(data[:third_end + 10]))  # and the file ends just after the third chunk
    summary = summarize(cut)
    assert "chunk at byte" in summary.problem and not summary.complete
    recover_log(cut, tmp_path / "fixed.mcap")
    original = [m.data for m in read_messages(small_chunked_log)]
    *kept, _note = [m.data for m in read_messages(tmp_path / "fixed.mcap")]
    first, third = chunks[0][1], chunks[2][1]
    # the third chunk's messages are kept, except those on channels the lost chunk introduced
    after = original[first + second_count : first + second_count + third]
    assert kept[:first] == original[:first] and first < len(kept) <= first + third
    assert all(message in after for message in kept[first:])

    whole = tmp_path / "damaged_whole.mcap"
    whole.write_bytes(bytes(data))  # the summary is intact: it knows every channel
    code, stdout, _ = cli("inspect", whole, "--validate")  # only reading every chunk finds the damage
    assert code == 2 and "INVALID" in stdout and "damaged chunk at byte" in stdout
    recovery = recover_log(whole, tmp_path / "fixed_whole.mcap")
    *kept, _note = [m.data for m in read_messages(tmp_path / "fixed_whole.mcap")]
    assert recovery.messages == len(kept) == len(original) - second_count
    assert kept == original[:first] + original[first + second_count :]


def test_the_writing_thread_keeps_the_order_and_reports_a_failed_write(tmp_path: Path) -> None:
    """Messages go to the MCAP writer on a second thread in batches: many batches, topics
    opened between them and a sync in the middle still read back in the order written; a
    write that fails there fails a later call with the one-line log error, nothing is
    written after it, and closing does not hide it."""
    from slamfront.errors import LogError
    from slamfront.mcaplog import writer as writer_module
    from slamfront.messages import RunEvent

    path = tmp_path / "ordered.mcap"
    with writer_module.RunLogWriter(path) as log:
        for n in range(3000):
            log.write(f"/topic_{n % 7 if n > 1000 else 0}", RunEvent(event="x" * 300, n_frames=n), n)
            if n == 1500:
                log.sync()
    frames = [m.decoded.n_frames for m in read_messages(path)]
    assert frames == list(range(3000)) and validate_log(path).valid

    class FailingStream:
        def __init__(self, stream: Any) -> None:
            self.stream, self.failed = stream, False

        def __getattr__(self, name: str) -> Any:
            return getattr(self.stream, name)

        def write(self, data: bytes) -> int:
            if self.failed:
                raise AssertionError("written after a failed write")
            if self.stream.size > 200_000:
                self.failed = True
                raise OSError(28, "No space left on device")
            return self.stream.write(data)

    log = writer_module.RunLogWriter(tmp_path / "full.mcap", chunk_size=50_000)
    log._writer._Writer__stream = FailingStream(log._stream)  # the MCAP writer's output, as a full disk
    with pytest.raises(LogError, match="cannot write the log: No space left on device"):
        for n in range(5000):
            log.write("/events", RunEvent(event=random.randbytes(300).hex(), n_frames=n), n)
        log.close()
    assert log.failed
    log.close()  # closing a failed log keeps what is on disk, quietly


def test_an_image_compressed_on_the_writing_thread_lands_in_its_place(tmp_path: Path) -> None:
    """write_foxglove_later builds its message on the writing thread, in the order written
    (the same bytes as write_foxglove's); a build that fails there fails a later call, and
    the log is left unfinalised as after a failed write, never closed as if complete."""
    import numpy as np

    from slamfront.errors import LogError
    from slamfront.mcaplog import foxglove
    from slamfront.mcaplog import writer as writer_module
    from slamfront.messages import RunEvent

    rng = np.random.default_rng(3)
    images = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(40)]
    eager, later = tmp_path / "eager.mcap", tmp_path / "later.mcap"
    for path in (eager, later):
        with writer_module.RunLogWriter(path) as log:
            for n, image in enumerate(images):
                log.write("/events", RunEvent(event="frame", n_frames=n), n)
                width = 32 if n % 2 else 64  # downscaled, or kept as it is (then copied)
                if path == eager:
                    log.write_foxglove("/camera/image", foxglove.compressed_image(image, n, width, "jpeg", 90), n)
                else:
                    bgr = foxglove.image_to_encode(image, width)
                    image[:] = 0  # the caller's array may change at once: the copy is what is encoded
                    log.write_foxglove_later("/camera/image", foxglove.CompressedImage,
                                             lambda bgr=bgr, n=n: foxglove.encoded_image(bgr, n, "jpeg", 90), n, 100)
    assert [(m.topic, m.data) for m in read_messages(eager)] == [(m.topic, m.data) for m in read_messages(later)]

    def broken() -> Any:
        raise ValueError("image encoding failed")

    log = writer_module.RunLogWriter(tmp_path / "broken.mcap")
    log.write_foxglove_later("/camera/image", foxglove.CompressedImage, broken, 0, 100)
    with pytest.raises(ValueError, match="image encoding failed"):
        for _ in range(10):
            log.sync()
    assert log.failed
    with pytest.raises(LogError, match="an earlier write failed"):
        log.write("/events", RunEvent(event="x", n_frames=1), 1)
    log.close()  # closing a failed log keeps what is on disk, quietly
    assert not validate_log(tmp_path / "broken.mcap").valid
