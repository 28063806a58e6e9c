"""mocapfix: human 3D motion infilling and denoising (XMAE, Motion-DVAE) on PyTorch Lightning."""

__version__ = "0.1.0"
