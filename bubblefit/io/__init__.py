"""Files: images through OpenImageIO (linear EXR/HDR, sRGB PNG/JPEG/TIFF)."""

from . import images
from .images import Image, read_image, write_image

__all__ = ["images", "Image", "read_image", "write_image"]
