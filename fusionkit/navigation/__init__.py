"""Navigation building blocks: initial alignment (source 000) and strapdown integration (source 004)."""

from .alignment import alignment_angles, alignment_quat

__all__ = ["alignment_angles", "alignment_quat"]
