"""Image files: `images.py` reads pictures and writes linear EXR and PNG (8 and 16 bit)."""
