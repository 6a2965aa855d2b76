"""Image stage: chessboard inner corners in panoramic, fisheye and pinhole images (docs/image_stage.md)."""

from .detect import ImageOptions, detect_corners

__all__ = ["ImageOptions", "detect_corners"]
