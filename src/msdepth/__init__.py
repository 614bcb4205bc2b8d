"""Self-supervised monocular depth estimation (Monodepth) with an MS-SSIM photometric loss."""

__version__ = "0.1.0"
