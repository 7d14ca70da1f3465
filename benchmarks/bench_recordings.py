"""Reading a large bag: frames per second through the ``ros_bag`` source against plain
``rosbags`` iteration over the same topics, and resident memory at the start and end.

A ROS 2 bag (MCAP storage) of at least ``--gigabytes`` is generated in a temporary folder
and deleted afterwards: a RealSense-like stream at 30 Hz, 640x480 ``rgb8`` colour, ``16UC1``
depth aligned to it, ``CameraInfo`` and a ``PoseStamped`` ground truth per frame (pixels
of a few synthetic-world frames, cycled). Each pass reads the whole bag in a fresh process:

- ``slamfront``: ``RosBag(...).frames()``: deserialise, pair depth and pose to each image
  by stamp, convert (depth to float32 metres), yield frames;
- ``rosbags``: ``AnyReader.messages()`` over the same four topics and ``deserialize`` of
  every message (the floor: what any reader built on rosbags must do).

Passes alternate (A B, B A, ...) because the machine is shared; the bag is read once
before timing so both read it from the page cache. Memory is the process's resident set
after the first 30 frames and after the last.

Run: nice .venv/bin/python benchmarks/bench_recordings.py [--gigabytes 1.05] [--rounds 3] [--tmpdir DIR]
Writes results/recordings.md.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import publish, table  # noqa: E402

TOPICS = {
    "image": "/camera/color/image_raw", "depth": "/camera/aligned_depth_to_color/image_raw",
    "info": "/camera/color/camera_info", "pose": "/ground_truth/pose",
}
START_FRAMES = 30


def rss_mb() -> float:
    """This process's resident set now, MB."""
    with open("/proc/self/statm") as statm:
        pages = int(statm.read().split()[1])
    import os

    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def generate(path: Path, gigabytes: float) -> tuple[int, int]:
    """Write the bag; returns (frames, bytes on disk)."""
    from slamfront_plugins.sources.synthetic import SyntheticWorld
    from tests.recordings import BagSpec, BagWriter

    world = SyntheticWorld(SyntheticWorld.Config(mode="stream", laps=1, frames_per_traversal=600, route_length_m=300,
                                                 image_width=640, image_height=480))
    samples = [world.frame_at(0, k) for k in range(0, 600, 100)]  # six distinct views, cycled
    per_frame = 640 * 480 * 3 + 640 * 480 * 2
    n = int(gigabytes * 1e9 / per_frame) + 1
    spec = BagSpec(ros=2, storage="mcap", image="rgb8", depth="16UC1", pose="PoseStamped")
    with BagWriter(path, spec) as writer:
        for i in range(n):
            sample = samples[i % len(samples)]
            frame = type(sample)(**{**sample.__dict__, "index": i, "timestamp": 1_700_000_000.0 + i / 30.0,
                                    "pose": world.world.pose_at(i * 0.05, 0.0, 0.0)})
            writer.write_frame(frame)
    size = sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return n, size


def child(mode: str, bag: Path) -> dict[str, float]:
    """One timed pass over the bag (in its own process; imports are not timed)."""
    from rosbags.highlevel import AnyReader

    from slamfront_plugins.sources.ros_bag import RosBag

    started = time.perf_counter()
    frames, rss_start = 0, 0.0
    if mode == "slamfront":
        source = RosBag(RosBag.Config(path=bag, image_topic=TOPICS["image"], depth_topic=TOPICS["depth"],
                                      camera_info_topic=TOPICS["info"], pose_topic=TOPICS["pose"]))
        for frame in source.frames():
            assert frame.depth is not None and frame.pose is not None
            frames += 1
            if frames == START_FRAMES:
                rss_start = rss_mb()
    else:
        with AnyReader([bag]) as reader:
            connections = [c for c in reader.connections if c.topic in TOPICS.values()]
            for connection, _, raw in reader.messages(connections=connections):
                message = reader.deserialize(raw, connection.msgtype)
                if connection.topic == TOPICS["image"]:
                    assert len(message.data)
                    frames += 1
                    if frames == START_FRAMES:
                        rss_start = rss_mb()
    seconds = time.perf_counter() - started
    return {"seconds": seconds, "frames": frames, "rss_start_mb": rss_start, "rss_end_mb": rss_mb()}


def own_work_ms(bag: Path, repeats: int = 200) -> float:
    """The source's own work for one frame (image and depth to arrays, pose to a matrix), ms:
    what it adds to reading and deserialising, measured on the bag's first messages."""
    from rosbags.highlevel import AnyReader

    from slamfront.formats import ros

    first: dict[str, object] = {}
    with AnyReader([bag]) as reader:
        for connection, _, raw in reader.messages(connections=reader.connections):
            first.setdefault(connection.topic, (reader.deserialize(raw, connection.msgtype), connection.msgtype))
            if len(first) == len(TOPICS):
                break
    image, depth, pose = first[TOPICS["image"]][0], first[TOPICS["depth"]][0], first[TOPICS["pose"]]
    times = []
    for _ in range(repeats):
        tick = time.perf_counter()
        ros.image_from_ros(image, "image")
        ros.depth_from_ros(depth, "depth")
        ros.pose_from_ros(pose[0], pose[1], "pose")
        times.append(time.perf_counter() - tick)
    return 1000 * statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gigabytes", type=float, default=1.05, help="size of the generated bag (default 1.05)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved pairs of passes (default 3)")
    parser.add_argument("--tmpdir", type=Path, default=None, help="where the bag is generated (then deleted)")
    parser.add_argument("--child", choices=["slamfront", "rosbags"], help=argparse.SUPPRESS)
    parser.add_argument("--bag", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.bag)))
        return
    folder = Path(tempfile.mkdtemp(prefix="slamfront-bench-bag-", dir=args.tmpdir))
    try:
        bag = folder / "realsense_like"
        tick = time.perf_counter()
        n_frames, size = generate(bag, args.gigabytes)
        print(f"generated {size / 1e9:.2f} GB, {n_frames} frames in {time.perf_counter() - tick:.0f} s", flush=True)
        for file in bag.rglob("*.mcap"):  # into the page cache: every pass reads from memory
            with open(file, "rb") as stream:
                while stream.read(1 << 24):
                    pass
        own_ms = own_work_ms(bag)
        runs: dict[str, list[dict[str, float]]] = {"slamfront": [], "rosbags": []}
        for round_number in range(args.rounds):
            order = ["slamfront", "rosbags"] if round_number % 2 == 0 else ["rosbags", "slamfront"]
            for mode in order:
                done = subprocess.run(
                    [sys.executable, __file__, "--child", mode, "--bag", str(bag)],
                    capture_output=True, text=True, check=True,
                )
                result = json.loads(done.stdout.strip().splitlines()[-1])
                runs[mode].append(result)
                print(mode, result, flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    rows = []
    ratios = []
    for i in range(args.rounds):
        ours, theirs = runs["slamfront"][i], runs["rosbags"][i]
        ratios.append(ours["seconds"] / theirs["seconds"])
        rows.append([i + 1, ours["seconds"], ours["frames"] / ours["seconds"], theirs["seconds"],
                     theirs["frames"] / theirs["seconds"], ratios[-1]])
    growth = [100 * (r["rss_end_mb"] / r["rss_start_mb"] - 1) for r in runs["slamfront"]]
    memory_rows = [[i + 1, r["rss_start_mb"], r["rss_end_mb"], growth[i]] for i, r in enumerate(runs["slamfront"])]
    body = "\n\n".join([
        f"Command: `nice .venv/bin/python benchmarks/bench_recordings.py --gigabytes {args.gigabytes} "
        f"--rounds {args.rounds}`. Machine: {cpu_model()} ({platform.machine()}), Python "
        f"{platform.python_version()}, shared with other work (passes interleaved, each in a fresh process, "
        "the bag in the page cache).",
        f"Bag: ROS 2, MCAP storage, {size / 1e9:.2f} GB, {n_frames} frames at 30 Hz of 640x480 `rgb8` + `16UC1` "
        "depth + `CameraInfo` + `PoseStamped` (written with rosbags, uncompressed, then deleted).",
        "## Time: the ros_bag source vs plain rosbags iteration over the same four topics\n\n" + table(
            ["round", "ros_bag s", "ros_bag frames/s", "rosbags s", "rosbags images/s", "time ratio"], rows),
        f"Median time ratio: **{statistics.median(ratios):.3f}x** plain rosbags iteration (target: at most 1.2x). "
        "The source deserialises the same messages, pairs depth and pose to each image by header stamp and "
        f"converts them: its own work per frame (image view, depth to float32 metres, pose matrix) is "
        f"**{own_ms:.2f} ms** (median of 200, in this process), against "
        f"{1000 * statistics.median(r['seconds'] / r['frames'] for r in runs['rosbags']):.2f} ms per frame "
        "for reading and deserialising. Both passes are dominated by copying ~1.5 MB per frame out of the MCAP "
        "chunks, and so by how the allocator serves buffers that large: profiled (cProfile) on a 0.4 GB bag, "
        "the plain loop spends about half its time in those copies (page faults on memory the allocator had "
        "given back to the system), which the source's pattern of allocations mostly avoids. Read a ratio under "
        "1 as \"no slower than reading the bag\", not as a speed-up.",
        "## Memory of the ros_bag pass (resident set)\n\n" + table(
            ["round", f"after {START_FRAMES} frames MB", "after the last MB", "growth %"], memory_rows),
        f"Largest growth from start to end: **{max(growth):.1f} %** (target: flat within 10 %): the source holds "
        "only the messages around the present, whatever the bag's size.",
    ])
    publish("recordings", "Reading recordings: the ros_bag source on a bag of over 1 GB", body)


if __name__ == "__main__":
    main()
