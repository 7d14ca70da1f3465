"""bow_bayes: does upscaling small images before feature extraction help recall?

Local features on small frames are few (a 64x32 Nordland thumbnail holds ~10-40 SIFT
keypoints at its own size); ``local_features``' ``scale`` resizes the image before
detection. It is off by default (``scale: 1``), and a recipe should upscale only where
that measurably helps recall. This benchmark measures recall at 100 % precision and
AUC-PR with and without upscaling, on every stream at hand:

- **synthetic**: the synthetic street at 160x120, two laps of 300 frames (day, then
  dusk), world seeds 3, 4 and 5 (none chose a parameter), SIFT 300;
- **Nordland chunks**: the route in summer then winter as one stream
  (``nordland_stream``, zeta 3), 300 frames per season from frames 0, 1,200 and 2,400,
  SIFT 100 (the ``nordland_bow`` recipe's features);
- **loop10**: the 10 desk images (image 10 revisits image 1) at their 640x480 and
  shrunk to 160x120 (area averaging), SIFT 400 (the ``loop10_bow`` recipe's).

Scales 1, 2 and 4 (loop10 at 640x480: 1 and 2). The detector: greedy vocabulary with the
derived SIFT thresholds, T_sim 0.2, STM 10 (loop10: 2), no time budget, so the features
are the only difference; place scoring. Also per frame: features kept (median),
extraction time (thread CPU, median) and detector time (thread CPU, median).

Run: .venv/bin/python benchmarks/bench_bow_upscale.py   (about 20 minutes; streams cached)
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bow_streams import Stream, StreamSpec, mean_sd, run_detector, score, source_stream, synthetic_stream  # noqa: E402
from common import publish, table  # noqa: E402

from slamfront.core.loops import LoopGroundTruth  # noqa: E402
from slamfront.data import data_root  # noqa: E402
from slamfront.frame import Frame  # noqa: E402
from slamfront.plugin import Source  # noqa: E402
from slamfront_plugins.loop_detectors.bow_bayes import BowBayes  # noqa: E402
from slamfront_plugins.sources.image_folder import ImageFolder  # noqa: E402
from slamfront_plugins.sources.nordland_stream import NordlandStream  # noqa: E402

SYNTHETIC_SEEDS = (3, 4, 5)
NORDLAND_STARTS = (0, 1200, 2400)
NORDLAND_FRAMES = 300
SCALES = (1.0, 2.0, 4.0)


class Shrunk(Source):
    """Another source's frames resized to ``size`` (area averaging), same ground truth."""

    name = "shrunk"

    def __init__(self, source: Source, size: tuple[int, int]) -> None:
        super().__init__(None)
        self.source = source
        self.size = size

    def __len__(self) -> int:
        return len(self.source)

    def frames(self) -> Iterator[Frame]:
        for frame in self.source.frames():
            small = cv2.resize(frame.image, self.size, interpolation=cv2.INTER_AREA)
            yield Frame(index=frame.index, timestamp=frame.timestamp, image=small, traversal=frame.traversal,
                        name=frame.name)

    def loop_ground_truth(self) -> LoopGroundTruth | None:
        return self.source.loop_ground_truth()


def loop10(size: tuple[int, int] | None) -> Source:
    source = ImageFolder(ImageFolder.Config(folder=Path("images/loop10"), fps=1.0, loops=[["1.png", "10.png"]]))
    return source if size is None else Shrunk(source, size)


def streams(group: str, scale: float) -> list[Stream]:
    if group == "synthetic":
        return [synthetic_stream(StreamSpec(seed, width=160, height=120, scale=scale)) for seed in SYNTHETIC_SEEDS]
    if group == "nordland":
        out = []
        for start in NORDLAND_STARTS:
            source = NordlandStream(NordlandStream.Config(root=data_root() / "nordland", start=start,
                                                          limit=NORDLAND_FRAMES))
            out.append(source_stream(f"nordland{start}_{NORDLAND_FRAMES}", StreamSpec(0, descriptor="sift",
                                     max_features=100, scale=scale), source))
        return out
    size = None if group == "loop10" else (160, 120)
    name = "loop10" if size is None else "loop10_160x120"
    return [source_stream(name, StreamSpec(0, descriptor="sift", max_features=400, scale=scale), loop10(size))]


GROUPS = {
    "synthetic": ("synthetic street 160x120, world seeds 3-5", SCALES, 10),
    "nordland": ("Nordland chunks (64x32), frames 0 / 1,200 / 2,400, 300 per season", SCALES, 10),
    "loop10": ("loop10 at 640x480", (1.0, 2.0), 2),
    "loop10_small": ("loop10 shrunk to 160x120", SCALES, 2),
}


def main() -> None:
    rows, verdicts = [], []
    for group, (label, scales, stm) in GROUPS.items():
        recalls: dict[float, list[float]] = {}
        for scale in scales:
            recall, auc, features, extraction, detector = [], [], [], [], []
            for stream in streams(group, scale):
                config = BowBayes.Config(descriptor_type="sift", stm_size=stm, time_budget_s=0.0)
                run = run_detector(config, stream, f"{group} x{scale:g}", progress=False)
                metrics = score(run, stream.truth)
                recall.append(metrics["recall_at_100p"])
                auc.append(metrics["auc_pr"])
                features.append(float(np.median([len(d) for d in stream.descriptors])))
                if stream.extraction_seconds is not None:
                    extraction.append(float(np.median(stream.extraction_seconds)) * 1000)
                detector.append(float(np.median(run.frame_cpu)) * 1000)
            recalls[scale] = recall
            rows.append([label, f"x{scale:g}", len(recall), mean_sd(recall), mean_sd(auc), f"{np.mean(features):.0f}",
                         f"{np.mean(extraction):.2f}" if extraction else "-", f"{np.mean(detector):.2f}"])
            print(rows[-1], flush=True)
        base = np.array(recalls[1.0])
        for scale in scales[1:]:
            gain = np.array(recalls[scale]) - base
            better = int(np.sum(gain > 0))
            verdicts.append(f"- {label}: x{scale:g} − x1 recall at 100 % precision {mean_sd(list(gain))} "
                            f"(higher on {better} of {len(gain)})")
    body = "\n\n".join([
        __doc__.split("Run:")[0].split("\n\n", 1)[1].strip(),
        table(["data", "scale", "streams", "R@100%P", "AUC-PR", "features per frame (median)",
               "extraction ms (median)", "detector ms (median, CPU)"], rows),
        "Paired differences (the same streams):\n\n" + "\n".join(verdicts),
    ])
    publish("bow_upscale", "bow_bayes: recall with and without upscaling small images", body,
            libraries=("numpy", "numba", "opencv-contrib-python-headless"))


if __name__ == "__main__":
    main()
