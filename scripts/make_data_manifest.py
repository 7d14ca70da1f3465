"""Write the pinned-data manifest (framework/slamfront/resources/data_manifest.json).

Lists every real dataset the tests read, with its public origin pinned to a commit or
a release, its licence and citation, and every file's size and SHA-256 computed from a
data root that holds the data (the one ``slamfront datasets path`` prints, or the
folder given). ``slamfront datasets fetch`` reads the manifest.

Run: .venv/bin/python scripts/make_data_manifest.py [DATA_ROOT]
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

from slamfront.data import data_root
from slamfront.manifest import MANIFEST

OPEN3D = "https://github.com/isl-org/open3d_downloads/releases/download"
SLAMBOOK2_LICENCE = "MIT (slambook2)"
SLAMBOOK2_CITE = "Gao Xiang, Zhang Tao et al., 14 Lectures on Visual SLAM, 2nd ed. (2019)"


def github(repo: str, commit: str, folder: str) -> str:
    """The raw-file base URL of ``folder`` in GitHub repository ``repo`` at ``commit`` (40 hex digits)."""
    if not re.fullmatch(r"[0-9a-f]{40}", commit):
        raise ValueError(f"{repo}: pin a full 40-digit commit, not {commit!r}")
    return f"https://raw.githubusercontent.com/{repo}/{commit}/{folder.strip('/')}/"


DATASETS: list[dict] = [
    dict(
        name="nordland", folder="nordland", files=None, archive=False,
        origin=github("TimQuelch/seqslam", "ea9ca6f6e5f7c5181357c5f649f0a3e0a6a6a8d0", "datasets/nordland_trimmed"),
        title="Nordland railway, summer and winter, every 10th frame, 64x32 grey",
        licence="CC BY 4.0 (NRK), as redistributed in TimQuelch/seqslam",
        citation="NRK, Nordlandsbanen minute by minute, season by season (2013); Sünderhauf et al. 2013",
    ),
    dict(
        name="loop10", folder="images/loop10", files=None, archive=False, origin=github("gaoxiang12/slambook2", "e62d9cd1f95bab337fb4251608543b71d004c420", "ch11/data"),
        title="10 indoor images with revisits (the bag-of-words loop demo)",
        licence=SLAMBOOK2_LICENCE, citation=SLAMBOOK2_CITE,
    ),
    dict(
        name="room_sample", folder="rgbd/room_sample", files=None, archive=False, origin=github("gaoxiang12/slambook2", "e62d9cd1f95bab337fb4251608543b71d004c420", "ch5/rgbd"),
        title="5 RGB-D frames of a room with poses", licence=SLAMBOOK2_LICENCE, citation=SLAMBOOK2_CITE,
    ),
    dict(
        name="icl_livingroom_sample", folder="rgbd/icl_livingroom_sample", files=None, archive=False,
        origin=github("gaoxiang12/slambook2", "33ad5a9aad93be37348fbb8e62b1d0c197950ff7", "ch12/dense_RGBD/data"),
        title="5 RGB-D frames of the ICL-NUIM living room with poses", licence=SLAMBOOK2_LICENCE,
        citation=f"{SLAMBOOK2_CITE}; Handa et al. 2014 (ICL-NUIM)",
    ),
    dict(
        name="fr1_gt_vs_est", folder="trajectories/fr1_gt_vs_est", files=None, archive=False,
        origin=github("gaoxiang12/slambook2", "7f74803e8f13fc3f3d86ab0995eaf2edf3dc5cc4", "ch4/example"),
        title="TUM fr1 ground-truth trajectory and an estimate of it", licence=SLAMBOOK2_LICENCE,
        citation=f"{SLAMBOOK2_CITE}; Sturm et al. 2012 (TUM RGB-D)",
    ),
    dict(
        name="redwood_sample", folder="rgbd/redwood_sample", files=None, archive=True,
        origin=f"{OPEN3D}/20220301-data/SampleRedwoodRGBDImages.zip",
        title="5 Redwood RGB-D frames with trajectory (Open3D's SampleRedwoodRGBDImages)",
        licence="MIT (Open3D test data)", citation="Choi et al. 2015 (Redwood); Zhou et al. 2018 (Open3D)",
    ),
    dict(
        name="open3d_feature_pair", folder="clouds/open3d_feature_pair", files=None, archive=True,
        origin=f"{OPEN3D}/20220201-data/DemoFeatureMatchingPointClouds.zip",
        title="two pre-aligned clouds with FPFH features (Open3D's DemoFeatureMatchingPointClouds)",
        licence="MIT (Open3D test data)", citation="Zhou et al. 2018 (Open3D)",
    ),
    dict(
        name="3dmatch_home_at", folder="clouds/3dmatch_home_at", files=None, archive=False,
        origin=github("MIT-SPARK/TEASER-plusplus", "e83aeabc8884d087f229dd96022494265b1010e1", "examples/example_data/3dmatch_sample"),
        title="one 3DMatch scan and the scene's gt.log (TEASER++ example data)",
        licence="3DMatch terms; TEASER++ example data (MIT)", citation="Zeng et al. 2017 (3DMatch); Yang et al. 2020 (TEASER++)",
    ),
    dict(
        name="bunny", folder="clouds", files=["bunny_res3.ply"], archive=False, origin=github("MIT-SPARK/TEASER-plusplus", "e83aeabc8884d087f229dd96022494265b1010e1", "examples/example_data"),
        renames={"bunny_res3.ply": "bun_zipper_res3.ply"},
        title="Stanford bunny, resolution 3 (TEASER++ example data)",
        licence="Stanford 3D Scanning Repository terms", citation="Turk and Levoy 1994 (Stanford bunny)",
    ),
    dict(
        name="posegraphs_se_sync", folder="posegraphs/se-sync", files=None, archive=False,
        origin=github("david-m-rosen/SE-Sync", "9b631b6b82d8aa7d32ab846412ae1c070412b7b6", "data"),
        title="pose-graph benchmarks (g2o) from SE-Sync", licence="LGPL-3.0 (SE-Sync)",
        citation="Rosen et al. 2019 (SE-Sync) and the datasets' authors",
    ),
    dict(
        name="posegraphs_slambook", folder="posegraphs/slambook",
        files=["INTEL.g2o", "M3500.g2o", "M3500a.g2o", "M3500b.g2o", "M3500c.g2o"], archive=False,
        origin=github("gaoxiang12/slambook", "e40feaf29d7ed4ad92e7be641b9ba4e58324f0d4", "pose_graph/2D"),
        title="INTEL and M3500 (with noisier variants) pose graphs from slambook", licence="MIT (slambook)",
        citation="Gao Xiang et al., 14 Lectures on Visual SLAM (2017); Olson et al. 2006 (M3500)",
    ),
    dict(
        name="posegraphs_slambook_sphere", folder="posegraphs/slambook", files=["sphere_slambook2.g2o"], archive=False,
        origin=github("gaoxiang12/slambook2", "e62d9cd1f95bab337fb4251608543b71d004c420", "ch10"), renames={"sphere_slambook2.g2o": "sphere.g2o"},
        title="the sphere pose graph of slambook2", licence=SLAMBOOK2_LICENCE, citation=SLAMBOOK2_CITE,
    ),
    dict(
        name="posegraphs_isam", folder="posegraphs/isam", files=None, archive=False,
        origin=github("rickytan/iSAM", "617b3ff154419f92d28e689a0f873d15cd999efe", "data"),
        title="iSAM's data sets and noise-free ground truth", licence="LGPL-2.1 (iSAM)",
        citation="Kaess et al. 2008 (iSAM); Olson et al. 2006 (manhattanOlson3500)",
    ),
    dict(
        name="posegraphs_gtsam", folder="posegraphs/gtsam", files=None, archive=False,
        origin=github("borglab/gtsam", "c98e4a79624eab18789dd3236c2fbbd0ca428ca5", "examples/Data"),
        title="GTSAM's example pose graphs and ground truth", licence="BSD-3-Clause (GTSAM)",
        citation="Dellaert et al. (GTSAM) and the datasets' authors",
    ),
]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def entry(spec: dict, root: Path) -> dict:
    folder = root / spec["folder"]
    if spec["files"] is None:
        names = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
    else:
        names = spec["files"]
    renames = spec.get("renames", {})
    files = [[name, (folder / name).stat().st_size, _digest(folder / name)] for name in names]
    return {
        "name": spec["name"], "folder": spec["folder"], "title": spec["title"], "origin": spec["origin"],
        "archive": spec["archive"], "licence": spec["licence"], "citation": spec["citation"],
        "renames": renames, "files": files,
    }


def main(argv: list[str]) -> int:
    root = Path(argv[0]) if argv else data_root()
    datasets = [entry(spec, root) for spec in DATASETS]
    manifest = {
        "about": "Pinned real data for slamfront's tests; written by scripts/make_data_manifest.py. "
        "files: [path in the dataset folder, size in bytes, SHA-256].",
        "datasets": datasets,
    }
    # one file per line keeps the JSON diffable
    lines = json.dumps(manifest, indent=1, ensure_ascii=False)
    MANIFEST.write_text(_compact_file_rows(lines) + "\n")
    n = sum(len(d["files"]) for d in datasets)
    size = sum(f[1] for d in datasets for f in d["files"])
    print(f"{MANIFEST}: {len(datasets)} datasets, {n} files, {size / 1e6:.1f} MB (from {root})")
    return 0


def _compact_file_rows(text: str) -> str:
    """``[\\n "a",\\n 1,\\n "h"\\n]`` rows of the files lists on one line each."""
    out: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.strip() == "[" and i + 4 < len(lines) and lines[i + 4].strip() in ("]", "],"):
            parts = [lines[i + k].strip().rstrip(",") for k in (1, 2, 3)]
            out.append(f"{line.rstrip()[:-1]}[{', '.join(parts)}{lines[i + 4].strip()}")
            i += 5
            continue
        out.append(line)
        i += 1
    return "\n".join(out)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
