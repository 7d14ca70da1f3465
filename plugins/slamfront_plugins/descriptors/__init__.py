"""Built-in descriptors."""

from slamfront import hookimpl

from slamfront_plugins.descriptors.downsampled import DownsampledImage


@hookimpl
def slamfront_descriptors() -> list[type]:
    return [DownsampledImage]
