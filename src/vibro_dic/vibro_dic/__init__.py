"""Sub-pixel digital image correlation (ZNCC + IC-GN) of ball and structure.

Public API: :func:`vibro_dic.mesh.mesh_points`, :class:`vibro_dic.tracker.DicTracker`,
:func:`vibro_dic.tracker.track_recording`, :func:`vibro_dic.noise.noise_study`,
:mod:`vibro_dic.speckle` (synthetic speckle with exact sub-pixel shifts). Imports without rclpy.
"""

from .mesh import mesh_points
from .tracker import DicTracker, MeshResult, track_recording

__all__ = ["DicTracker", "MeshResult", "mesh_points", "track_recording"]
