"""Built-in sources."""

from slamfront import hookimpl
from slamfront_plugins.sources.euroc import Euroc
from slamfront_plugins.sources.image_folder import ImageFolder
from slamfront_plugins.sources.kitti_odometry import KittiOdometry
from slamfront_plugins.sources.mixed import MixedScenes
from slamfront_plugins.sources.nordland_stream import NordlandStream
from slamfront_plugins.sources.paired_datasets import GardensPoint, Nordland, PairedFolders, UofA, VprBench
from slamfront_plugins.sources.rgbd import RgbdFolder, TumRgbd
from slamfront_plugins.sources.ros_bag import RosBag
from slamfront_plugins.sources.synthetic import SyntheticWorld
from slamfront_plugins.sources.video import Video


@hookimpl
def slamfront_sources() -> list[type]:
    return [
        SyntheticWorld, ImageFolder, RgbdFolder, TumRgbd, Nordland, NordlandStream, GardensPoint, UofA, VprBench,
        PairedFolders, MixedScenes, RosBag, Euroc, KittiOdometry, Video,
    ]
