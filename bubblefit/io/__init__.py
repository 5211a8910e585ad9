"""Files: images through OpenImageIO (linear EXR/HDR, sRGB PNG/JPEG/TIFF); spectrometer readings."""

from . import images, spectra
from .images import Image, read_image, write_image
from .spectra import Spectrum, read_spectrum

__all__ = ["images", "spectra", "Image", "read_image", "write_image", "Spectrum", "read_spectrum"]
