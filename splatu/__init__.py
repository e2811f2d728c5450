"""splatu: CPU 3D Gaussian Splatting in pure PyTorch with view-dependent SH uncertainty."""

__version__ = "0.1.0"
