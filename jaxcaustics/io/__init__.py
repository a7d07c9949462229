"""Pictures and height maps in and out: PNG (8 and 16 bit) and linear EXR (`images.py`).

Writers write to a temporary name beside the file and rename it (`files.py`), so a
user's file is never left half-written.
"""

from .images import read_exr, read_image, write_exr, write_png, write_png_linear16

__all__ = ["read_image", "write_png", "write_png_linear16", "read_exr", "write_exr"]
