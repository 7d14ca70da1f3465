"""Built-in descriptors."""

from slamfront import hookimpl
from slamfront_plugins.descriptors.downsampled import DownsampledImage
from slamfront_plugins.descriptors.local_features import LocalFeaturesDescriptor
<<<<<<< HEAD
from slamfront_plugins.descriptors.seqslam_thumbnail import SeqSlamThumbnail
=======
from slamfront_plugins.descriptors.rst_shelo import RstShelo
>>>>>>> main


@hookimpl
def slamfront_descriptors() -> list[type]:
<<<<<<< HEAD
    return [DownsampledImage, LocalFeaturesDescriptor, SeqSlamThumbnail]
=======
    return [DownsampledImage, LocalFeaturesDescriptor, RstShelo]
>>>>>>> main
