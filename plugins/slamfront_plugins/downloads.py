"""The public datasets the built-in sources read: where each is published and how it unpacks.

Listed in the ``slamfront.datasets`` entry-point group (``DOWNLOADS``: source plugin name
-> its datasets), so ``slamfront datasets`` shows them without importing a source (or
NumPy); each source's ``downloads`` class attribute holds the same records.
"""

from __future__ import annotations

from slamfront.datasets import DatasetDownload

NORDLAND_COMMIT = "ea9ca6f6e5f7c5181357c5f649f0a3e0a6a6a8d0"

NORDLAND = DatasetDownload(
    name="nordland",
    title="Nordland railway, summer/winter, every 10th frame, 64x32 grey (the OpenSeqSLAM-style set)",
    url=f"https://codeload.github.com/TimQuelch/seqslam/tar.gz/{NORDLAND_COMMIT}",
    homepage="https://nrkbeta.no/2013/01/15/nordlandsbanen-minute-by-minute-season-by-season/",
    license="CC BY (NRK); frames as redistributed in github.com/TimQuelch/seqslam",
    archive="tar",
    members=f"seqslam-{NORDLAND_COMMIT}/datasets/nordland_trimmed/",
    strip=f"seqslam-{NORDLAND_COMMIT}/datasets/nordland_trimmed/",
    expect=("summer", "winter"),
)
GARDENS_POINT = DatasetDownload(
    name="gardens_point",
    title="Gardens Point Walking (QUT): day_left, day_right, night_right, 200 frames each",
    url="https://www.tu-chemnitz.de/etit/proaut/datasets/GardensPoint_Walking.zip",
    homepage="https://wiki.qut.edu.au/display/cyphy/Day+and+Night+with+Lateral+Pose+Change+Datasets",
    license="QUT research dataset; cite Suenderhauf et al. 2015 (mirror of TU Chemnitz, used by the VPR tutorial)",
    archive="zip",
)
UOFA = DatasetDownload(
    name="uofa",
    title="UofA day/evening (University of Alberta, Husky robot), 646 frames each",
    url=None,
    homepage="https://github.com/siam1251/Fast-SeqSLAM",
    license="research use; cite Siam and Zhang 2017",
    manual=(
        "The authors share it as a Google Drive folder "
        "(https://drive.google.com/drive/folders/0B5OUuYYB6c4CUktyMncxZXQxcDQ, linked from "
        "github.com/siam1251/Fast-SeqSLAM/dataset). Download its day_evening folder and put it at "
        "{cache}/uofa/day_evening (or anywhere, and set the uofa source's root)."
    ),
)


_TUM = "https://cvg.cit.tum.de/rgbd/dataset"


def _tum_sequence(name: str, group: str, title: str) -> DatasetDownload:
    """A TUM RGB-D benchmark sequence archive, unpacked so its folder holds rgb.txt directly."""
    folder = f"rgbd_dataset_{group}_{name}"
    return DatasetDownload(
        name=f"tum_{group.replace('freiburg', 'fr')}_{name}",
        title=title,
        url=f"{_TUM}/{group}/{folder}.tgz",
        homepage="https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download",
        license="CC BY 4.0; cite Sturm et al. 2012 (TUM publishes no checksum: the first download records one)",
        archive="tar",
        members=f"{folder}/",
        strip=f"{folder}/",
        expect=("rgb.txt", "depth.txt", "groundtruth.txt"),
    )


TUM_FR1_DESK = _tum_sequence(
    "desk", "freiburg1", "TUM RGB-D fr1/desk: hand-held, four desks of an office (Barbosa 2017, table 8)"
)
TUM_FR2_PIONEER_SLAM = _tum_sequence(
    "pioneer_slam", "freiburg2", "TUM RGB-D fr2/pioneer_slam: a Pioneer robot in a hall (Barbosa 2017, tables 1-7)"
)


DOWNLOADS: dict[str, tuple[DatasetDownload, ...]] = {
    "nordland": (NORDLAND,),
    "gardens_point": (GARDENS_POINT,),
    "uofa": (UOFA,),
    "tum_rgbd": (TUM_FR1_DESK, TUM_FR2_PIONEER_SLAM),
}
"""Source plugin name -> the datasets it reads (``slamfront datasets download NAME``)."""
