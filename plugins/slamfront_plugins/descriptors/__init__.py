"""Built-in descriptors."""

from slamfront import hookimpl
from slamfront_plugins.descriptors.downsampled import DownsampledImage
from slamfront_plugins.descriptors.local_features import LocalFeaturesDescriptor
from slamfront_plugins.descriptors.onnx_model import OnnxDescriptor
from slamfront_plugins.descriptors.rst_shelo import RstShelo
from slamfront_plugins.descriptors.seqslam_thumbnail import SeqSlamThumbnail


@hookimpl
def slamfront_descriptors() -> list[type]:
    return [DownsampledImage, LocalFeaturesDescriptor, OnnxDescriptor, RstShelo, SeqSlamThumbnail]
